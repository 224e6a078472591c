"""Drivers advance a Simulation: one per `physics.scheme` (what moves the particles)."""

from psph.drivers.static import StaticDriver

DRIVERS = {"none": StaticDriver}


def driver_for(scene):
    return DRIVERS[scene.physics.scheme]


def describe_model(scene) -> list:
    """One line per model term the scene activates (what `psph info` lists)."""
    d = scene.domain
    init = scene.initial
    particles = f"particles: {init.type}"
    if init.sigma_over_dx:
        particles += f" + Gaussian perturbation sigma = {init.sigma_over_dx:g} dx (seed {init.seed})"
    if init.velocity != "zero":
        particles += f"; initial velocity and pressure: analytic {init.velocity}"
    lines = [f"kernel {d.kernel}, h = {d.h_over_dx:g} dx = {d.h:g}, support 2h, {d.dimension}-D", particles]
    lines += DRIVERS[scene.physics.scheme].describe(scene)
    return lines
