"""Solid profiles in 2-D: body nodes with normals and tangents, and the solid particles filling a body.

Following section III of the clone-particle paper (seed 004): the profile is discretised by body nodes
every ds = dx / 4, each with the unit normal pointing out of the fluid (into the solid) and the tangent
completing a right-handed frame (t = (-n_y, n_x)). The solid is filled over one kernel support behind the
profile: here with the points of the fluid lattice (spacing dx) that lie inside the solid within that
distance, so that a solid particle sits where a fluid particle would; an unrotated box takes a
lattice continued from its own sides (boundaries.extended_lattice), its rows dx/2, 3 dx/2, ... behind
each, and fitted between them where they are off the lattice. Each solid particle takes the normal,
tangent and node index of its closest body node and keeps its distance s_j to the profile (seed 004 eq. 5-7).
Distances to the profile (s_i, s_j: "the distances of the particles i and j from the body contour", seed
004 after eq. 6) are to the polyline through the body nodes (contour_distance), not to the closest node.

Shapes: `box` (the fluid is inside: the outer walls of a tank or cavity), `rectangle` and `ellipse` (the
fluid is outside: immersed bodies), each with a centre, a size and an angle; `polygon`, given by its
corners: the fluid inside (a tank of any straight-sided shape, e.g. seed 002's trapezoidal tank) or outside
(an immersed body: seed 004's triangular cylinder).
"""

from dataclasses import dataclass

import numpy as np


@dataclass
class Profile:
    """Body nodes of one profile (reference configuration)."""

    nodes: np.ndarray  # (m, 2) positions
    normals: np.ndarray  # (m, 2) unit normals out of the fluid
    fluid_inside: bool  # True for a box (walls around the fluid)
    # (m, 2): each node's neighbours along the contour, before and after it (itself at an open line's end);
    # None: the nodes run once round one closed contour, in order
    ends: np.ndarray = None

    def __post_init__(self):
        if self.ends is None:
            k = np.arange(len(self.nodes))
            self.ends = np.stack([np.roll(k, 1), np.roll(k, -1)], axis=1)

    @property
    def tangents(self) -> np.ndarray:
        return np.stack([-self.normals[:, 1], self.normals[:, 0]], axis=1)


def _rotation(angle_deg):
    a = np.deg2rad(angle_deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def rectangle_profile(center, size, angle_deg, ds, fluid_inside) -> Profile:
    """Nodes every ~ds along a rectangle; corner nodes take the bisecting normal."""
    w, h = size[0] / 2.0, size[1] / 2.0
    corners = np.array([[-w, -h], [w, -h], [w, h], [-w, h]])
    outward = [np.array([0.0, -1.0]), np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([-1.0, 0.0])]
    nodes, normals = [], []
    for k in range(4):
        a, b = corners[k], corners[(k + 1) % 4]
        length = np.linalg.norm(b - a)
        count = max(int(round(length / ds)), 1)
        for s in range(count):  # the corner at s = 0 gets the mean of the two sides' normals
            nodes.append(a + (b - a) * s / count)
            n = outward[k] + (outward[k - 1] if s == 0 else 0.0)
            normals.append(n / np.linalg.norm(n))
    normals = np.array(normals)
    if fluid_inside:  # walls around the fluid: the normal points out of the box
        pass
    else:  # an immersed body: the normal points into the body (out of the fluid)
        normals = -normals
    rot = _rotation(angle_deg)
    return Profile(np.asarray(center) + np.array(nodes) @ rot.T, normals @ rot.T, fluid_inside)


def ellipse_profile(center, semi_axes, angle_deg, ds, fluid_inside=False) -> Profile:
    """Nodes at equal arc length ~ds along an ellipse (normals into the ellipse for an immersed body)."""
    a, b = semi_axes
    theta = np.linspace(0.0, 2.0 * np.pi, 20001)
    pts = np.stack([a * np.cos(theta), b * np.sin(theta)], axis=1)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    count = max(int(round(arc[-1] / ds)), 8)
    t = np.interp(np.arange(count) * arc[-1] / count, arc, theta)
    nodes = np.stack([a * np.cos(t), b * np.sin(t)], axis=1)
    outward = np.stack([np.cos(t) / a, np.sin(t) / b], axis=1)
    outward /= np.linalg.norm(outward, axis=1)[:, None]
    normals = outward if fluid_inside else -outward
    rot = _rotation(angle_deg)
    return Profile(np.asarray(center) + nodes @ rot.T, normals @ rot.T, fluid_inside)


def counterclockwise(vertices) -> np.ndarray:
    """The polygon's corners as an (m, 2) array, reordered counter-clockwise if given clockwise."""
    v = np.asarray(vertices, dtype=np.float64)
    area2 = np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])
    return v if area2 > 0 else v[::-1].copy()


def polygon_profile(vertices, ds, fluid_inside=True) -> Profile:
    """Nodes every ~ds along a polygon's sides, from its first corner counter-clockwise; the normal points
    out of the fluid (out of the polygon with the fluid inside, into it for an immersed body) and a corner
    node takes the bisector of its two sides' normals, as a rectangle's do (rectangle_profile: a polygon with
    a rectangle's corners, from its lower left one, has the same nodes and normals)."""
    v = counterclockwise(vertices)
    edges = np.roll(v, -1, axis=0) - v
    lengths = np.linalg.norm(edges, axis=1)
    outward = np.stack([edges[:, 1], -edges[:, 0]], axis=1) / lengths[:, None]  # right of a counter-clockwise side
    nodes, normals = [], []
    for k in range(len(v)):
        count = max(int(round(lengths[k] / ds)), 1)
        for s in range(count):
            nodes.append(v[k] + edges[k] * s / count)
            n = outward[k] + (outward[k - 1] if s == 0 else 0.0)
            normals.append(n / np.linalg.norm(n))
    normals = np.array(normals)
    return Profile(np.array(nodes), normals if fluid_inside else -normals, fluid_inside)


def polygon_centroid(vertices) -> np.ndarray:
    """The area centroid of a simple polygon (the shoelace formula)."""
    v = np.asarray(vertices, dtype=np.float64)
    w = np.roll(v, -1, axis=0)
    cross = v[:, 0] * w[:, 1] - w[:, 0] * v[:, 1]
    return ((v + w) * cross[:, None]).sum(axis=0) / (3.0 * cross.sum())


def sharp_corner_points(vertices, fluid_inside, dx) -> tuple:
    """One point in the solid at each corner of a polygon whose solid side is narrower than 90 degrees (an
    immersed triangle's corners, a weir's crest): on the corner's bisector, dx/2 from both sides, where the
    lattice's first row would stand. Lattice points fill such a tip only from 1.2-1.8 dx behind the corner (a
    60-degree corner at dx = D/10, D/20, D/50, D the side), which leaves the fluid there no solid to mirror:
    the triangular cylinder's fluid entered it and the run stopped. Seed 004 fills a body along its normals
    instead, which reaches the tip. Returns (points, their corners)."""
    v = counterclockwise(vertices)
    before, after = np.roll(v, 1, axis=0) - v, np.roll(v, -1, axis=0) - v
    before /= np.linalg.norm(before, axis=1)[:, None]
    after /= np.linalg.norm(after, axis=1)[:, None]
    # the interior angle at each corner (counter-clockwise: convex where the turn is anticlockwise)
    convex = before[:, 0] * after[:, 1] - before[:, 1] * after[:, 0] < 0.0
    opening = np.arccos(np.clip((before * after).sum(axis=1), -1.0, 1.0))
    interior = np.where(convex, opening, 2.0 * np.pi - opening)
    solid = 2.0 * np.pi - interior if fluid_inside else interior
    bisector = (before + after) * np.where(convex == (not fluid_inside), 1.0, -1.0)[:, None]
    sharp = solid < 0.5 * np.pi - 1e-9
    bisector = bisector[sharp] / np.linalg.norm(bisector[sharp], axis=1)[:, None]
    return v[sharp] + bisector * (0.5 * dx / np.sin(0.5 * solid[sharp]))[:, None], v[sharp]


def distance_to_polygon(vertices, points) -> np.ndarray:
    """Distance of every point to the polygon's sides."""
    v = np.asarray(vertices, dtype=np.float64)
    a, b = v, np.roll(v, -1, axis=0)
    ab = b - a
    rel = points[:, None, :] - a[None, :, :]
    along = np.clip((rel * ab).sum(axis=2) / (ab * ab).sum(axis=1), 0.0, 1.0)
    return np.linalg.norm(rel - along[:, :, None] * ab[None, :, :], axis=2).min(axis=1)


def shape_spec(body) -> tuple:
    """What `inside` needs to know of a scene body (a BodySpec)."""
    if body.shape == "polygon":
        return ("polygon", body.vertices, None, 0.0)
    return ("ellipse" if body.shape == "ellipse" else "rectangle", body.center, body.size, body.angle)


def inside(profile_spec, pos) -> np.ndarray:
    """Mask of points inside the shape (its interior, whichever side the fluid is on)."""
    shape, center, size, angle = profile_spec
    if shape == "polygon":  # center: the corners
        from matplotlib.path import Path

        return Path(np.asarray(center, dtype=np.float64)).contains_points(pos)
    local = (pos - np.asarray(center)) @ _rotation(angle)
    if shape == "ellipse":
        return (local[:, 0] / size[0]) ** 2 + (local[:, 1] / size[1]) ** 2 < 1.0
    return (np.abs(local[:, 0]) < size[0] / 2.0) & (np.abs(local[:, 1]) < size[1] / 2.0)


def nearest_nodes(profile, points):
    """(index of the closest node, distance to the contour) for every point, in the profile's reference
    configuration: the closest node by a k-d tree, the distance by contour_distance."""
    from scipy.spatial import cKDTree

    if len(points) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    _, idx = cKDTree(profile.nodes).query(points)
    return idx.astype(np.int64), contour_distance(profile.nodes, profile.ends, idx, points)


def contour_distance(nodes, ends, closest, points) -> np.ndarray:
    """Distance of each of `points` to the contour, the polyline through the body `nodes` (`ends`: each node's
    neighbours along it, Profile.ends), over the two segments that meet at the point's closest node
    `closest` (the kernel psph.compute.walls.contour_distance). Seed 004 mirrors with the distances to the body
    contour (s_i, s_j after eq. 6); the distance to the closest node, which psph took before, exceeds it by up
    to sqrt(s^2 + ds^2 / 4) - s with nodes ds apart: 3.1% at s = dx/2 and 11.8% at s = dx/4 (a walls audit).
    On a polygon's sides the polyline is the contour; along an ellipse it lies within ds^2 / (8 R) of it."""
    from psph.compute.walls import contour_distance as kernel

    return kernel(np.ascontiguousarray(nodes, dtype=np.float64), np.ascontiguousarray(ends, dtype=np.int64),
                  np.ascontiguousarray(closest, dtype=np.int64), np.ascontiguousarray(points, dtype=np.float64))


def solid_particles(profile, spec, lattice_points, thickness, with_index=False):
    """Lattice points inside the solid side of `profile` within `thickness` of it.

    Returns (positions, node index, distance to the profile) of the solid particles, and with_index their
    indices in lattice_points."""
    is_in = inside(spec, lattice_points)
    solid_side = np.flatnonzero(~is_in if profile.fluid_inside else is_in)
    candidates = lattice_points[solid_side]
    node, dist = nearest_nodes(profile, candidates)
    keep = dist <= thickness
    out = candidates[keep], node[keep], dist[keep]
    return (*out, solid_side[keep]) if with_index else out
