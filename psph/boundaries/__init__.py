"""Solid walls and bodies: geometry, solid particles, clone-particle mirroring (seed 004), forces."""

import numpy as np

from psph.boundaries.bodies import bounds, make_bodies
from psph.boundaries.geometry import inside, shape_spec
from psph.particles import FieldSpec

SOLID_FIELDS = (FieldSpec("body", (), np.int64), FieldSpec("ref_position", ("d",)), FieldSpec("normal", ("d",)),
                FieldSpec("ref_normal", ("d",)), FieldSpec("wall_distance"), FieldSpec("wall_accel", ("d",)),
                FieldSpec("wall_node", (), np.int64), FieldSpec("wall_velocity", ("d",)))
SOLID_HALO_FIELDS = ("body", "normal", "wall_distance", "wall_accel", "wall_velocity")


def thickness(scene) -> float:
    """Depth of the solid layer: one kernel support (seed 004 section III)."""
    return scene.domain.support


def in_fluid_region(scene, pos) -> np.ndarray:
    """Which lattice points the fluid fills: the fill region (or the drop's disc), inside every box, outside
    immersed bodies and inflow buffers."""
    keep = np.ones(len(pos), dtype=bool)
    if scene.initial.drop_radius > 0:
        keep &= ((pos - np.asarray(scene.domain.center)) ** 2).sum(axis=1) < scene.initial.drop_radius ** 2
    lo, hi = scene.initial.fill_lower, scene.initial.fill_upper
    if lo:
        keep &= np.all(pos >= np.asarray(lo), axis=1)
    if hi:
        keep &= np.all(pos <= np.asarray(hi), axis=1)
    for b in scene.bodies:
        is_in = inside(shape_spec(b), pos)
        keep &= is_in if b.container else ~is_in
    if scene.inflow:
        from psph.boundaries.open import make_inflows

        for f in make_inflows(scene):
            keep &= ~f.inside(pos)
    return keep


def extended_lattice(scene, lower=None, upper=None):
    """Lattice points and their volumes: the fluid's lattice inside the domain or, given an unrotated box
    container's sides [lower, upper], between them (fitted where they are off the lattice); continued one
    solid thickness beyond the sides along non-periodic axes.

    Beyond each side the rows continue from that side, (k + 1/2) dx away from it, so that a container's
    first solid row sits dx/2 behind its wall as it does when the side lies on the lattice's midlines:
    otherwise (seed 001's tank, 5.367 H long) the solid rows would stand up to dx behind the wall, the fluid
    would settle as close to the wall as to them, and cross it. Unless both of a box's sides along an axis
    lie on lattice midlines, the n = round(L / dx) rows between them are spaced L / n (within dx / (2 n)
    of dx), so that they meet the rows beyond both sides without a gap: from the domain's lattice, the
    tank's bottom-right corner had one of 1.34 dx (H/dx = 20), a hole in the concentration into which the
    shifting drove the fluid particles there, through the floor (docs/results.md, "Dam break"). Fitted rows drift
    from the fluid's lattice, which starts at the domain's lower corner: by 0.13 dx under the dam-break
    column's right end at H/dx = 20. Each point's volume is the product of its spacings."""
    axes, spacings = lattice_rows(scene, lower, upper)
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, scene.domain.dimension)
    return points, np.prod(np.stack(np.meshgrid(*spacings, indexing="ij"), axis=-1), axis=-1).ravel()


def lattice_rows(scene, lower=None, upper=None):
    """extended_lattice's rows along each axis: ([coordinates per axis], [spacings per axis])."""
    d = scene.domain
    m = int(np.ceil((thickness(scene) + d.dx) / d.dx))
    fitted = lower is not None
    lower = d.lower if lower is None else lower
    upper = d.upper if upper is None else upper
    axes, spacings = [], []
    for a in range(d.dimension):
        axis = d.lower[a] + (np.arange(int(round((d.upper[a] - d.lower[a]) / d.dx))) + 0.5) * d.dx
        spacing = np.full(len(axis), d.dx)
        if not d.periodic[a]:
            rows = np.arange(m) + 0.5
            tol = 1e-9 * d.dx  # a side on a lattice point: that point is the wall's, not a row
            n = max(int(round((upper[a] - lower[a]) / d.dx)), 1)
            on_lattice = abs(upper[a] - lower[a] - n * d.dx) < tol and \
                abs((lower[a] - d.lower[a]) / d.dx - round((lower[a] - d.lower[a]) / d.dx)) < 1e-9
            if fitted and not on_lattice:
                inner = lower[a] + (np.arange(n) + 0.5) * (upper[a] - lower[a]) / n
                spacing = np.concatenate([np.full(m, d.dx), np.full(n, (upper[a] - lower[a]) / n),
                                          np.full(m, d.dx)])
            else:  # the domain's own lattice points between the sides (the fluid's)
                inner = axis[(axis > lower[a] + tol) & (axis < upper[a] - tol)]
                spacing = np.full(len(inner) + 2 * m, d.dx)
            axis = np.concatenate([lower[a] - rows[::-1] * d.dx, inner, upper[a] + rows * d.dx])
        axes.append(axis)
        spacings.append(spacing)
    return axes, spacings


def solid_arrays(scene, rank, size, first_gid):
    """This rank's share of every body's solid particles (fields by name), gids from first_gid on."""
    bodies = make_bodies(scene)
    lattice = extended_lattice(scene)
    parts = []
    for body in bodies:
        if body.spec.model == "ghost":  # images of the fluid, made at every stage (psph.compute.walls)
            continue
        own = lattice
        if body.spec.shape == "box" and body.spec.angle == 0.0:
            own = extended_lattice(scene, *bounds(body.spec))
        pos, normal, dist, node, vol = body.solid_particles(*own, thickness(scene))
        parts.append((body, pos, normal, dist, node, vol))
    total = sum(len(p[1]) for p in parts)
    start, stop = total * rank // size, total * (rank + 1) // size
    if total == 0:
        return None
    pos = np.concatenate([p[1] for p in parts])
    normal = np.concatenate([p[2] for p in parts])
    dist = np.concatenate([p[3] for p in parts])
    node = np.concatenate([p[4] for p in parts])
    body = np.concatenate([np.full(len(p[1]), p[0].index) for p in parts])
    kind = np.concatenate([np.full(len(p[1]), int(p[0].kind)) for p in parts])
    sl = slice(start, stop)
    return {"gid": first_gid + np.arange(start, stop, dtype=np.int64), "position": pos[sl].copy(),
            "ref_position": pos[sl].copy(), "normal": normal[sl], "ref_normal": normal[sl],
            "wall_distance": dist[sl], "body": body[sl], "wall_node": node[sl], "kind": kind[sl].astype(np.int8),
            "volume": np.concatenate([p[5] for p in parts])[sl].copy()}
