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


def fluid_mask(scene, pos) -> np.ndarray:
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


def extended_lattice(scene, lower=None, upper=None) -> np.ndarray:
    """The fluid's lattice inside [lower, upper] (default: the domain; an unrotated box container's sides)
    continued one solid thickness beyond it along non-periodic axes.

    Beyond each side the rows continue from that side, (k + 1/2) dx away from it, so that a container's
    first solid row sits dx/2 behind its wall as it does when the side lies on the lattice's midlines:
    otherwise (seed 001's tank, 5.367 H long) the solid rows would stand up to dx behind the wall, the fluid
    would settle as close to the wall as to them, and cross it."""
    d = scene.domain
    m = int(np.ceil((thickness(scene) + d.dx) / d.dx))
    lower = d.lower if lower is None else lower
    upper = d.upper if upper is None else upper
    axes = []
    for a in range(d.dimension):
        axis = d.lower[a] + (np.arange(int(round((d.upper[a] - d.lower[a]) / d.dx))) + 0.5) * d.dx
        if not d.periodic[a]:
            rows = np.arange(m) + 0.5
            sides = []
            for side in (lower[a], upper[a]):  # side = lattice line k dx + offset
                k = int(round((side - d.lower[a]) / d.dx))
                offset = side - d.lower[a] - k * d.dx
                sides.append((k, 0.0 if abs(offset) < 1e-9 * d.dx else offset))
            (k_lo, off_lo), (k_hi, off_hi) = sides
            tol = 1e-9 * d.dx  # a side on a lattice point: that point is the wall's, not a row
            axis = np.concatenate([d.lower[a] + off_lo + (k_lo - rows[::-1]) * d.dx,
                                   axis[(axis > lower[a] + tol) & (axis < upper[a] - tol)],
                                   d.lower[a] + off_hi + (k_hi + rows) * d.dx])
        axes.append(axis)
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d.dimension)


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
        pos, normal, dist, node = body.solid_particles(own, thickness(scene))
        parts.append((body, pos, normal, dist, node))
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
            "volume": np.full(stop - start, scene.domain.dx ** scene.domain.dimension)}
