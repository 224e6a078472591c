"""Drivers advance a Simulation: one per `physics.scheme` (what moves the particles)."""

from psph.drivers.fluid import FluidDriver
from psph.drivers.kinematic import KinematicDriver
from psph.drivers.static import StaticDriver
from psph.scene.schema import FLUID_SCHEMES

DRIVERS = {"none": StaticDriver, "kinematic": KinematicDriver, **{name: FluidDriver for name in FLUID_SCHEMES}}


def driver_for(scene):
    return DRIVERS[scene.physics.scheme]


def describe_model(scene) -> list:
    """One line per model term the scene activates (what `psph info` lists)."""
    d = scene.domain
    init = scene.initial
    particles = f"particles: {init.type}"
    if init.sigma_over_dx:
        particles += f" + Gaussian perturbation sigma = {init.sigma_over_dx:g} dx (seed {init.seed})"
    if init.drop_radius > 0:
        particles += f" filling a drop of radius {init.drop_radius:g} (free surface all round)"
    if init.velocity == "inflow":
        first = scene.inflow[0]
        particles += (f"; initial velocity: the first inflow's, {tuple(first.velocity)}"
                      + (" in its parabolic profile across it" if first.profile == "parabolic" else ""))
    elif init.velocity == "uniform":
        particles += f"; initial velocity: uniform, {tuple(init.uniform_velocity)}"
    elif init.velocity != "zero":
        particles += f"; initial velocity and pressure: analytic {init.velocity}"
    lines = [f"kernel {d.kernel}, h = {d.h_over_dx:g} dx = {d.h:g}, support 2h, {d.dimension}-D", particles]
    lines += DRIVERS[scene.physics.scheme].describe(scene)
    if scene.physics.scheme not in FLUID_SCHEMES or scene.shifting.method == "iips":
        lines += shifting_description(scene)
    return lines


def shifting_description(scene) -> list:
    """The shifting terms, described without building solvers."""
    s = scene.shifting
    if s.method == "iips":
        i = scene.iips
        cap = f"at most {i.max_newton} Newton iterations per call"
        if i.beta > 0:
            trigger = f"threshold beta = {i.beta:g} x Linf(grad C) after {i.pre_newton} pre-procedure iterations"
        elif i.threshold > 0:
            trigger = f"threshold Linf(grad C) <= {i.threshold:g}"
        else:
            trigger = "no threshold"
            if scene.physics.scheme in FLUID_SCHEMES:
                cap = f"so every call runs all {i.max_newton} Newton iterations (set iips.threshold)"
        return [f"shifting: IIPS (thesis ch. 8), Procedure {i.procedure}, {trigger}, {cap}, on failure: {i.on_failure}",
                "IIPS linear solver: PETSc KSP prefix -iips_ (default bcgs + jacobi, rtol 1e-2)"]
    if s.method == "explicit_iterative":
        return [f"shifting: explicit Fickian dx = -D grad C, D = {s.diffusion:g} h^2 (thesis eq. 6.13), "
                f"{s.max_iterations} iterations (static) / {s.iterations_per_step} per step"]
    return ["shifting: none"]
