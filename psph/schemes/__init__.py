"""Fluid schemes: the physics operators of a flow, composed from the scene (only declared terms run)."""


def make_scheme(scene):
    if scene.physics.scheme == "riemann_ale":
        from psph.schemes.riemann_ale import RiemannALE

        return RiemannALE(scene)
    from psph.schemes.delta_ale import DeltaALE

    return DeltaALE(scene)
