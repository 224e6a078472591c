"""The scene: what a TOML file may say, with types, defaults and limits.

Key paths are part of psph's interface (scripts set them with --set): keep them stable.
"""

import math
from dataclasses import dataclass

from psph.compute.smoothing import KERNEL_NAMES
from psph.errors import SceneError
from psph.scene.validate import option


@dataclass(frozen=True)
class DomainSpec:
    dimension: int = option(doc="number of space dimensions", choices=(1, 2, 3))
    lower: tuple[float, ...] = option(doc="lower corner of the box", length="dimension")
    upper: tuple[float, ...] = option(doc="upper corner of the box", length="dimension")
    periodic: tuple[bool, ...] = option(doc="periodicity of each axis", length="dimension")
    dx: float = option(doc="initial particle spacing (the resolution)", gt=0.0)
    h_over_dx: float = option(2.0, doc="smoothing length over particle spacing", ge=1.0, le=4.0)
    kernel: str = option("wendland_c6", doc="smoothing kernel", choices=KERNEL_NAMES)

    def check(self, path):
        for a in range(self.dimension):
            if not self.upper[a] > self.lower[a]:
                raise SceneError(f"{path}.upper[{a}]", f"must exceed lower[{a}] = {self.lower[a]}, "
                                 f"got {self.upper[a]}")
            length = self.upper[a] - self.lower[a]
            cells = length / self.dx
            if self.periodic[a] and abs(cells - round(cells)) > 1e-8 * max(1.0, cells):
                raise SceneError(f"{path}.dx", f"must divide the periodic length {length:g} of axis {a} "
                                 f"(got {length:g}/{self.dx:g} = {cells:.6g} spacings)")

    @property
    def h(self) -> float:
        return self.h_over_dx * self.dx

    @property
    def support(self) -> float:
        return 2.0 * self.h

    def lattice_shape(self) -> tuple:
        """Particles per axis of the initial lattice."""
        return tuple(int(round((self.upper[a] - self.lower[a]) / self.dx)) for a in range(self.dimension))

    def estimated_particles(self) -> int:
        return math.prod(self.lattice_shape())


@dataclass(frozen=True)
class InitialSpec:
    type: str = option("lattice", doc="initial particle arrangement", choices=("lattice",))
    sigma_over_dx: float = option(0.0, doc="std. deviation of the Gaussian position perturbation, in dx",
                                  ge=0.0, le=1.0)
    seed: int = option(0, doc="seed of the perturbation (results do not depend on the rank count)",
                       ge=0, lt=2**63)
    velocity: str = option("zero", doc="initial velocity and pressure: zero (no fields) or the analytic "
                           "taylor_green vortex (2-D bi-periodic square)", choices=("zero", "taylor_green"))


@dataclass(frozen=True)
class PhysicsSpec:
    scheme: str = option("none", doc="what moves the particles: none (a static distribution)",
                         choices=("none",))
    reference_velocity: float = option(1.0, doc="reference velocity U (the analytic fields' amplitude)", gt=0.0)
    density: float = option(1.0, doc="reference density rho0", gt=0.0)


@dataclass(frozen=True)
class ShiftingSpec:
    method: str = option("none", doc="particle shifting method", choices=("none",))


@dataclass(frozen=True)
class TimeSpec:
    t_end: float = option(0.0, doc="end time of the simulation", ge=0.0)


@dataclass(frozen=True)
class OutputSpec:
    every: float = option(0.0, doc="simulated time between snapshots (0: initial and final only)", ge=0.0)


@dataclass(frozen=True)
class DiagnosticsSpec:
    test_wavelength: float = option(
        0.5, doc="wavelength l of the test function f = sin(2 pi x/l) + cos(2 pi y/l) (thesis eq. 3.6), "
        "in domain length units; l/dx particles per wavelength", gt=0.0)


@dataclass(frozen=True)
class NeighboursSpec:
    skin: float = option(0.1, doc="Verlet skin of the neighbour lists, as a fraction of the kernel support",
                         ge=0.0, le=1.0)
    rebalance_threshold: float = option(
        1.1, doc="rebalance the ranks when max/mean owned particles exceeds this at a rebuild", ge=1.0)


@dataclass(frozen=True)
class Scene:
    name: str = option(doc="name of the scene")
    domain: DomainSpec = option(doc="the box and its discretisation")
    initial: InitialSpec = option(InitialSpec(), doc="initial condition")
    physics: PhysicsSpec = option(PhysicsSpec(), doc="physical model")
    shifting: ShiftingSpec = option(ShiftingSpec(), doc="particle shifting")
    time: TimeSpec = option(TimeSpec(), doc="time integration")
    output: OutputSpec = option(OutputSpec(), doc="what is written and when")
    diagnostics: DiagnosticsSpec = option(DiagnosticsSpec(), doc="diagnostics")
    neighbours: NeighboursSpec = option(NeighboursSpec(), doc="neighbour lists and load balance")

    def check(self, path):
        if self.initial.velocity == "taylor_green":
            d = self.domain
            square = d.dimension == 2 and all(d.periodic) and math.isclose(
                d.upper[0] - d.lower[0], d.upper[1] - d.lower[1])
            if not square:
                raise SceneError("initial.velocity", "taylor_green needs a 2-D bi-periodic square domain")
        reach = (1.0 + self.neighbours.skin) * self.domain.support
        for a in range(self.domain.dimension):
            length = self.domain.upper[a] - self.domain.lower[a]
            if self.domain.periodic[a] and length <= reach:
                raise SceneError("domain.dx", f"periodic axis {a} (length {length:g}) must be longer than the "
                                 f"kernel support plus skin ({reach:g}); refine dx or lower h_over_dx")
        wavelength = self.diagnostics.test_wavelength
        for a in range(min(self.domain.dimension, 2)):
            if self.domain.periodic[a]:
                waves = (self.domain.upper[a] - self.domain.lower[a]) / wavelength
                if abs(waves - round(waves)) > 1e-8 * max(1.0, waves):
                    raise SceneError("diagnostics.test_wavelength",
                                     f"must divide the periodic length of axis {a} (got {waves:.6g} waves)")
