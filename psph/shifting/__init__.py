"""Particle shifting. Each method is an object built from the scene; `shifting.method = "none"` builds
NoShifting, whose correction leaves the particles where they are (and costs nothing)."""

from psph.shifting.base import NoShifting, ShiftReport


def make_shifting(scene, comm):
    """The shifting object the scene asks for."""
    method = scene.shifting.method
    if method == "iips":
        from psph.boundaries.free_surface import make_free_surface
        from psph.shifting.iips import ImplicitShifting

        # a static distribution's free surface: its particles stay (thesis 10.2.1), as in a flow's pre-procedure
        return ImplicitShifting(scene.iips, comm, surface=make_free_surface(scene))
    if method == "explicit_iterative":
        from psph.shifting.explicit import ExplicitIterativeShifting

        return ExplicitIterativeShifting(scene.shifting, scene.domain)
    return NoShifting()


__all__ = ["NoShifting", "ShiftReport", "make_shifting"]
