"""The Riemann SPH-ALE scheme (thesis 000 section 5.5, eq. 5.48-5.49; Vila 1999, Oger et al. 2016).

Volume V, mass m = V rho and momentum m v evolve; rho = m / V. The fluxes between particles are those of
a Riemann problem at the pair's midpoint (MUSCL with minmod, the linearised acoustic solver), which
replaces the delta-ALE family's diffusive terms D^rho and D^m. The transport velocity v0 = v + du of an
explicit shifting law (du = 0 without one, and with IIPS, which moves the particles after the step) enters
the fluxes directly: there are no separate du-terms. Viscosity, gravity and the equation of state are
those of the delta-ALE family. Kernels in psph.compute.riemann; time step of the fluid driver (the CFL
condition of eq. 5.52 and the viscous limit). Walls and bodies (clone particles, fixed ghosts) enter
through the Riemann problem between each fluid particle and its mirrored solid neighbours
(psph.compute.walls: RIEMANN_WALLS); the fluid's own fluxes then skip the solids.
"""

import numpy as np

from psph.compute.riemann import riemann_ale_rhs, velocity_gradient
from psph.compute.walls import RIEMANN_WALLS, RIEMANN_WALLS_LOW
from psph.particles import FieldSpec
from psph.schemes.delta_ale import DeltaALE


class RiemannALE(DeltaALE):
    def __init__(self, scene):
        super().__init__(scene)
        self.tait = scene.physics.eos == "tait"
        self.limited = scene.physics.muscl_limiter == "minmod"
        self.low_dissipation = scene.physics.riemann_dissipation == "low"
        self.reads_grad_rho = True  # the MUSCL states (eq. 5.49)
        self.wall_variant = RIEMANN_WALLS_LOW if self.low_dissipation else RIEMANN_WALLS

    def describe(self) -> list:
        limiter = "minmod" if self.limited else "no limiter"
        solver = "the low-dissipation pressure of Zhang et al. 2017" if self.low_dissipation else "acoustic"
        lines = ["scheme: Riemann SPH-ALE (thesis eq. 5.48): volume, mass and momentum fluxes of a linearised "
                 f"Riemann solver ({solver}) on MUSCL states (eq. 5.49, {limiter})",
                 f"equation of state: {self.eos.name}, c0 = {self.c0:g}, rho0 = {self.rho0:g}",
                 f"viscosity: {'Morris et al. (1997)' if self.morris else 'pi_ij (seed 001 eq. 11)'} operator, "
                 f"nu = {self.nu:g}"]
        if np.any(self.gravity):
            lines.append(f"gravity {tuple(self.gravity)}")
        if self.free_stream is not None:
            lines.append(f"free stream {tuple(self.free_stream)} reached at t = {self.free_stream_ramp:g}")
        if self.walls.active:
            lines.append("walls: the Riemann problem between each fluid particle and its mirrored solid "
                         "neighbours (a partial Riemann problem, Marongiu 2007), no mass through them")
        if self.no_pull:
            lines.append("clone walls in the free-surface region push and never pull: the Riemann pressure on "
                         "them p^E >= 0 (physics.wall_adhesion = false)")
        return lines + [self.shift.describe()] + self.walls.describe()

    def field_specs(self):
        return super().field_specs() + [FieldSpec("grad_velocity", ("d", "d"))]

    def halo_fields(self):
        return super().halo_fields() + ["grad_velocity"]

    def state(self, system) -> dict:
        p = system.particles
        return {"position": p.owned("position").copy(), "volume": p.owned("volume").copy(),
                "mass": p.owned("mass").copy(), "momentum": p.owned("mass")[:, None] * p.owned("velocity")}

    def set_state(self, system, state, refresh_positions=True) -> None:
        """Set the state (positions, volumes, masses, momenta) and refresh the halo. Collective."""
        p = system.particles
        p.owned("position")[:] = state["position"]
        p.owned("volume")[:] = state["volume"]
        p.owned("mass")[:] = state["mass"]
        p.owned("velocity")[:] = state["momentum"] / state["mass"][:, None]
        p.owned("density")[:] = state["mass"] / state["volume"]
        p.owned("pressure")[:] = self.eos.pressure(p.owned("density"))
        if refresh_positions:
            system.refresh(["position"])

    def rhs(self, system, t, dt) -> dict:
        """d(state)/dt of the owned particles. Collective (halo exchanges)."""
        p = system.particles
        walls = self.place_walls(system, t)
        system.refresh(["density", "mass", "velocity", "volume", "pressure"])
        self.shift_and_density_gradient(system, t, dt, fluid_only=walls)
        v0 = self.shift.transport(p, owned=False)
        velocity_gradient(p["position"], p["volume"], p["velocity"], self.pairs, p["grad_velocity"])
        system.refresh(["grad_rho", "grad_velocity"])
        n, d = p.n_owned, p.dim
        d_vol, d_mass, d_mom = np.zeros(n), np.zeros(n), np.zeros((n, d))
        riemann_ale_rhs(p["position"], p["volume"], p["density"], p["mass"], p["velocity"], v0, p["grad_rho"],
                        p["grad_velocity"], self.pairs, self.c0, self.rho0, self.tait, self.mu, self.morris,
                        self.gravity, d_vol, d_mass, d_mom, limited=self.limited,
                        low_dissipation=self.low_dissipation, kind=p["kind"] if walls else None)
        self.walls.add(system, self, t, d_vol, d_mom)
        if self.free_stream is not None:
            self._drive_free_stream(system, t, d_mom)
        return {"position": v0[:n].copy(), "volume": d_vol, "mass": d_mass, "momentum": d_mom}
