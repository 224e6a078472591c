"""Fluid schemes: the physics operators of a flow, composed from the scene (only declared terms run)."""

FLUID_SCHEMES = ("delta_ale", "delta_ale_const_mass", "delta_ale_const_volume")


def make_scheme(scene):
    from psph.schemes.delta_ale import DeltaALE

    return DeltaALE(scene)
