"""Solid walls and bodies: geometry, solid particles, clone-particle mirroring (seed 004), forces."""

import numpy as np

from psph.boundaries.bodies import make_bodies
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


def extended_lattice(scene) -> np.ndarray:
    """The fluid's lattice continued one solid thickness beyond the domain along non-periodic axes."""
    d = scene.domain
    margin = thickness(scene) + d.dx
    axes = []
    for a in range(d.dimension):
        lo, hi = d.lower[a], d.upper[a]
        k_lo = -int(np.ceil(margin / d.dx)) if not d.periodic[a] else 0
        k_hi = int(round((hi - lo) / d.dx)) + (int(np.ceil(margin / d.dx)) if not d.periodic[a] else 0)
        axes.append(lo + (np.arange(k_lo, k_hi) + 0.5) * d.dx)
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d.dimension)


def solid_arrays(scene, rank, size, first_gid):
    """This rank's share of every body's solid particles (fields by name), gids from first_gid on."""
    bodies = make_bodies(scene)
    lattice = extended_lattice(scene)
    parts = []
    for body in bodies:
        if body.spec.model == "ghost":  # images of the fluid, made at every stage (psph.compute.walls)
            continue
        pos, normal, dist, node = body.solid_particles(lattice, thickness(scene))
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
