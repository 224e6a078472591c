"""Body profiles and solid particles (seed 004 section III): nodes every ds = dx/4 on the profile, unit
normals pointing out of the fluid, and solid particles filling one kernel support behind the profile."""

import numpy as np
import pytest

from psph.boundaries.geometry import (
    distance_to_polygon,
    ellipse_profile,
    inside,
    nearest_nodes,
    rectangle_profile,
    solid_particles,
)

DX = 0.05


def spacing(nodes):
    """Distances between consecutive nodes round the closed profile."""
    return np.linalg.norm(np.diff(np.vstack([nodes, nodes[:1]]), axis=0), axis=1)


@pytest.mark.parametrize("angle", [0.0, 35.0])
def test_ellipse_nodes_lie_on_the_profile_at_equal_arc_length(angle):
    center, (a, b) = np.array([1.0, 2.0]), (0.5, 0.2)
    prof = ellipse_profile(center, (a, b), angle, DX / 4)
    c, s = np.cos(np.deg2rad(angle)), np.sin(np.deg2rad(angle))
    local = (prof.nodes - center) @ np.array([[c, -s], [s, c]])
    assert np.allclose((local[:, 0] / a) ** 2 + (local[:, 1] / b) ** 2, 1.0, atol=1e-12)
    gaps = spacing(prof.nodes)
    assert np.allclose(gaps, DX / 4, rtol=0.02)  # chords of equal arcs ds = dx/4 (the count rounded)
    assert np.allclose(np.linalg.norm(prof.normals, axis=1), 1.0)
    chords = np.roll(prof.nodes, -1, axis=0) - np.roll(prof.nodes, 1, axis=0)
    chords /= np.linalg.norm(chords, axis=1)[:, None]
    assert np.abs(np.sum(prof.normals * chords, axis=1)).max() < 0.01  # normal to the profile
    assert np.all(np.sum(prof.normals * (center - prof.nodes), axis=1) > 0)  # into the body: out of the fluid
    assert np.allclose(prof.tangents, np.stack([-prof.normals[:, 1], prof.normals[:, 0]], axis=1))


@pytest.mark.parametrize("fluid_inside", [False, True])
def test_rectangle_nodes_and_normals(fluid_inside):
    center, size = np.array([0.0, 0.0]), (1.0, 0.5)
    prof = rectangle_profile(center, size, 20.0, DX / 4, fluid_inside=fluid_inside)
    assert len(prof.nodes) == int(2 * (size[0] + size[1]) / (DX / 4))
    assert np.allclose(spacing(prof.nodes), DX / 4)
    outward = np.sum(prof.normals * (prof.nodes - center), axis=1) > 0
    assert np.all(outward == fluid_inside)  # a box's normals leave the box, a body's enter it
    assert np.allclose(np.linalg.norm(prof.normals, axis=1), 1.0)
    corners = np.abs(np.abs(prof.normals @ np.array([[np.cos(0.349066), -np.sin(0.349066)],
                                                    [np.sin(0.349066), np.cos(0.349066)]])))
    assert np.sum(np.isclose(corners[:, 0], np.sqrt(0.5))) == 4  # the corners take the bisecting normal


@pytest.mark.parametrize("shape", ["ellipse", "rectangle"])
def test_solid_particles_fill_one_support_behind_the_profile(shape):
    """Every lattice point inside the body within one support (2h = 4 dx) of the profile is a solid
    particle, no other; each knows its closest node and its distance to the profile."""
    center, size, thickness = np.array([1.0, 1.0]), (0.5, 0.3), 4 * DX
    spec = (shape, center, size, 10.0)
    prof = (ellipse_profile(center, size, 10.0, DX / 4) if shape == "ellipse"
            else rectangle_profile(center, size, 10.0, DX / 4, fluid_inside=False))
    g = np.arange(0.0, 2.0, DX) + DX / 2
    lattice = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    pos, node, dist = solid_particles(prof, spec, lattice, thickness)
    assert np.all(inside(spec, pos)) and len(pos) > 0
    assert np.array_equal(node, np.linalg.norm(pos[:, None] - prof.nodes[None], axis=2).argmin(axis=1))
    polyline = distance_to_polygon(prof.nodes, lattice)  # the contour through all the nodes, by brute force
    assert np.allclose(dist, distance_to_polygon(prof.nodes, pos), rtol=0.0, atol=1e-12)
    expected = inside(spec, lattice) & (polyline <= thickness)
    assert len(pos) == expected.sum()
    assert dist.max() <= thickness


@pytest.mark.parametrize("shape", ["ellipse", "rectangle"])
def test_distances_are_to_the_contour_not_to_the_closest_node(shape):
    """Seed 004's s_i and s_j are distances to the body contour (after eq. 6). Points s = dx/4 and dx/2 off
    a side, halfway between two nodes, were given the distance to the closest node, sqrt(s^2 + ds^2/4):
    11.8% and 3.1% too far (a walls audit). On a rectangle the contour is its sides, exactly; along an
    ellipse the nodes' polyline lies within ds^2 / (8 R) of it."""
    center, size, angle, ds = np.array([1.0, 1.0]), (0.5, 0.3), 10.0, DX / 4
    prof = (ellipse_profile(center, size, angle, ds) if shape == "ellipse"
            else rectangle_profile(center, size, angle, ds, fluid_inside=False))
    mid = 0.5 * (prof.nodes + np.roll(prof.nodes, -1, axis=0))  # halfway between neighbouring nodes
    away = -0.5 * (prof.normals + np.roll(prof.normals, -1, axis=0))  # out of the body (the fluid's side)
    away /= np.linalg.norm(away, axis=1)[:, None]
    plain = np.ones(len(mid), dtype=bool)  # a rectangle: no corner between the two nodes
    if shape == "rectangle":
        plain = np.abs(prof.normals - np.roll(prof.normals, -1, axis=0)).sum(axis=1) < 1e-12
    for s in (DX / 4, DX / 2):
        points = (mid + s * away)[plain]
        node, dist = nearest_nodes(prof, points)
        if shape == "rectangle":
            c, r = np.cos(np.deg2rad(angle)), np.sin(np.deg2rad(angle))
            unit = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])
            corners = center + (unit * np.asarray(size) / 2) @ [[c, r], [-r, c]]
            assert np.allclose(dist, distance_to_polygon(corners, points), rtol=0.0, atol=1e-12)
        assert np.allclose(dist, s, rtol=0.0, atol=ds**2 / (8 * min(size) ** 2 / max(size)) + 1e-12)
        assert np.linalg.norm(points - prof.nodes[node], axis=1).min() > s * (1 + 0.02)  # the old distance


def test_periodic_plates_are_open_lines_whose_distance_holds_across_the_domain_s_edges():
    """A container spanning a periodic axis is two plates continued a period to either side
    (bodies._periodic_plates): each an open line, its end nodes their own neighbours; a point off a plate,
    anywhere along the period and between nodes, is at its height above it."""
    from psph.boundaries.bodies import make_bodies
    from psph.scene.load import load_scene
    from tests.helpers import CASES

    scene = load_scene(CASES / "couette.toml")
    prof = make_bodies(scene)[0].profile
    lines = len(prof.nodes) // 2
    assert prof.ends[0, 0] == 0 and prof.ends[lines - 1, 1] == lines - 1
    assert prof.ends[lines, 0] == lines and prof.ends[-1, 1] == len(prof.nodes) - 1
    lower, upper = np.asarray(scene.domain.lower), np.asarray(scene.domain.upper)
    floor = prof.nodes[prof.normals[:, 1] < 0, 1][0]
    x = np.linspace(lower[0], upper[0], 97)
    for s in (scene.domain.dx / 4, scene.domain.dx / 2, 0.3):
        points = np.stack([x, np.full_like(x, floor + s)], axis=1)
        assert np.allclose(nearest_nodes(prof, points)[1], s, rtol=0.0, atol=1e-12)


def test_solid_layer_has_the_area_of_one_support():
    """The solid particles of an ellipse (semi-axes 0.6 x 0.5) over a thickness t = 0.2, below its smallest
    radius of curvature (b^2/a = 0.42), fill the inner parallel layer, whose area is t P - pi t^2 (Steiner's
    formula, P the perimeter): their count times dx^2 matches it within 1%."""
    a, b, t, dx = 0.6, 0.5, 0.2, 0.01
    center = np.array([1.0, 1.0])
    prof = ellipse_profile(center, (a, b), 25.0, dx / 4)
    g = np.arange(0.0, 2.0, dx) + dx / 2
    lattice = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    pos, _, _ = solid_particles(prof, ("ellipse", center, (a, b), 25.0), lattice, t)
    theta = np.linspace(0.0, 2.0 * np.pi, 4096, endpoint=False)  # a periodic integrand: the mean is spectral
    perimeter = 2.0 * np.pi * np.hypot(a * np.sin(theta), b * np.cos(theta)).mean()
    assert len(pos) * dx * dx == pytest.approx(t * perimeter - np.pi * t * t, rel=0.01)


@pytest.mark.parametrize("law", ["constant", "ramp", "spheric6", "oscillate"])
def test_motion_laws_are_their_own_derivatives(law):
    """s'(t) and s''(t) of every law are the derivatives of s(t) and s'(t) (central differences), s'
    reaches 1 (its velocity) and never exceeds it, and s(0) = s'(0) = 0 except where the law starts moving
    at once (constant, oscillate: s'(0) = 1)."""
    from psph.boundaries.bodies import MotionLaw
    from psph.scene.schema import MotionSpec

    unit = MotionLaw(MotionSpec(law=law, ramp_time=0.4, period=0.7))
    t = np.linspace(0.01, 2.5, 400)
    e = 1e-3 if law == "spheric6" else 1e-6  # spheric6's s and s' are tabulated every 5e-5: difference across
    s, ds, dds = (np.array(v) for v in zip(*(unit(x) for x in t)))
    plus, minus = (np.array([unit(x)[:2] for x in t + sign * e]) for sign in (1.0, -1.0))
    tol = 1e-3 if law == "spheric6" else 1e-6
    assert np.allclose((plus[:, 0] - minus[:, 0]) / (2 * e), ds, atol=tol)
    assert np.allclose((plus[:, 1] - minus[:, 1]) / (2 * e), dds, atol=tol)
    assert np.abs(ds).max() <= 1.0 + 1e-12 and np.isclose(np.abs(ds).max(), 1.0, atol=1e-4)
    assert unit(0.0)[0] == 0.0 and unit(0.0)[1] == (1.0 if law in ("constant", "oscillate") else 0.0)


def test_translation_and_rotation_follow_their_own_laws():
    """A body translating at constant velocity while its rotation oscillates: centre c0 + v t, angle
    omega P / (2 pi) sin(2 pi t / P), and the material velocity and acceleration of a point of the body are
    the time derivatives of its position."""
    from psph.boundaries.bodies import Body
    from psph.scene.schema import BodySpec, MotionSpec

    motion = MotionSpec(law="constant", velocity=(0.5, 0.25), angular_velocity=2.0, rotation_law="oscillate",
                        period=0.8)
    body = Body(BodySpec(name="b", shape="rectangle", center=(1.0, 2.0), size=(1.0, 0.5), motion=motion), 0, 0.1,
                (1.0, 0.0))
    t = 0.3
    c, rot, v, omega, a, alpha = body.rigid(t)
    theta = 2.0 * 0.8 / (2 * np.pi) * np.sin(2 * np.pi * t / 0.8)
    assert np.allclose(c, [1.0 + 0.5 * t, 2.0 + 0.25 * t]) and np.allclose(v, [0.5, 0.25]) and np.allclose(a, 0.0)
    assert np.allclose(rot, [[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    assert np.isclose(omega, 2.0 * np.cos(2 * np.pi * t / 0.8))
    assert np.isclose(alpha, -2.0 * 2 * np.pi / 0.8 * np.sin(2 * np.pi * t / 0.8))
    x_ref = np.array([[1.4, 2.2], [0.7, 1.8]])
    e = 1e-6
    x, u, acc = body.material(x_ref, t)
    (xp, up, _), (xm, um, _) = body.material(x_ref, t + e), body.material(x_ref, t - e)
    assert np.allclose((xp - xm) / (2 * e), u, atol=1e-7) and np.allclose((up - um) / (2 * e), acc, atol=1e-6)
    assert Body(BodySpec(name="b", shape="ellipse", center=(1.0, 2.0), size=(1.0, 0.5),
                         motion=MotionSpec(rotation_law="oscillate", angular_velocity=1.0)), 0, 0.1, (1.0, 0.0)).moves


def test_an_ellipse_s_reference_length_is_its_major_axis_however_written():
    """The force coefficients' default D of an ellipse is its major axis (psph keys), also with the long
    semi-axis given second: [0.5, 0.2] at -20 degrees and [0.2, 0.5] at 70 are one body (D was 2 size[0],
    and the second ellipse's coefficients 2.5 times the first's, its moment's 6.25)."""
    from psph.boundaries.bodies import Body
    from psph.scene.schema import BodySpec

    lengths = [Body(BodySpec(name="e", shape="ellipse", center=(1.0, 1.0), size=size, angle=angle), 0, 0.05,
                    (1.0, 0.0)).reference_length for size, angle in (((0.5, 0.2), -20.0), ((0.2, 0.5), 70.0))]
    assert lengths == [1.0, 1.0]


# box containers whose sides are not on the lattice's midlines: seed 001's tank (5.367 x 3) at three
# resolutions, a tank inside its domain off the lattice, and one whose sides fall on lattice points
OFF_LATTICE_CONTAINERS = [("dam_break", ["domain.dx=0.025"]), ("dam_break", ["domain.dx=0.05"]),
                          ("dam_break", ["domain.dx=0.1"]),
                          ("hydrostatic_tank", ["bodies.0.center=[0.96,0.607]", "bodies.0.size=[1.83,1.111]"]),
                          ("hydrostatic_tank", ["bodies.0.center=[1.0,0.6]", "bodies.0.size=[1.475,1.025]"])]


def container_solids(case, sets):
    """(the scene, its solid particles' fields, its container's lower and upper sides)."""
    from psph.boundaries import solid_arrays
    from psph.boundaries.bodies import bounds
    from psph.scene.load import load_scene
    from tests.helpers import CASES

    scene = load_scene(CASES / f"{case}.toml", sets)
    return scene, solid_arrays(scene, 0, 1, 0), *bounds(scene.bodies[0])


@pytest.mark.parametrize("case, sets", OFF_LATTICE_CONTAINERS)
def test_a_container_s_solid_rows_stand_from_each_of_its_sides(case, sets):
    """A box container whose sides are not on the lattice's midlines (OFF_LATTICE_CONTAINERS): behind every
    side the solid rows stand dx/2, 3 dx/2, ... away, as behind a side on the midlines, and fill one
    support."""
    from psph.boundaries import thickness

    scene, solids, lower, upper = container_solids(case, sets)
    dx = scene.domain.dx
    pos, dist = solids["position"], solids["wall_distance"]
    rows = (np.arange(int(np.ceil(thickness(scene) / dx))) + 0.5) * dx
    for a in range(2):
        for side, beyond in ((lower[a], pos[:, a] < lower[a]), (upper[a], pos[:, a] > upper[a])):
            gaps = np.unique(np.round(np.abs(pos[beyond, a] - side), 12))
            assert np.allclose(gaps, rows[rows <= thickness(scene) + 1e-12], rtol=0.0, atol=1e-12)
    inside = np.all((pos > lower) & (pos < upper), axis=1)
    assert not inside.any() and dist.min() == pytest.approx(dx / 2, rel=1e-3)


@pytest.mark.parametrize("case, sets", OFF_LATTICE_CONTAINERS)
def test_a_container_s_solid_rows_meet_at_its_corners_without_a_gap(case, sets):
    """Along the first solid row behind each side, the points are spaced L / round(L / dx) between the
    box's sides (within dx / (2 n) of dx) and dx beyond them, with no gap where the rows behind two sides meet (from
    the domain's lattice, seed 001's tank at H/dx = 20 had 1.34 dx at its bottom-right corner); each
    solid's volume is the product of its spacings."""
    scene, solids, lower, upper = container_solids(case, sets)
    dx = scene.domain.dx
    pos, vol = solids["position"], solids["volume"]
    spacing = []
    for a in range(2):
        n = round((upper[a] - lower[a]) / dx)
        spacing.append((upper[a] - lower[a]) / n)
        for behind in (lower[1 - a] - dx / 2, upper[1 - a] + dx / 2):  # the first row behind either side
            along = np.sort(pos[np.abs(pos[:, 1 - a] - behind) < 1e-9, a])
            gaps = np.diff(along)
            assert along[0] < lower[a] and along[-1] > upper[a]
            assert gaps.max() <= dx * (1.0 + 0.5 / n) + 1e-12 and gaps.min() >= dx * (1.0 - 0.5 / n) - 1e-12
    inner = (pos > np.asarray(lower)) & (pos < np.asarray(upper))
    expected = np.prod(np.where(inner, np.asarray(spacing), dx), axis=1)
    assert np.allclose(vol, expected, rtol=1e-12, atol=0.0)


@pytest.mark.parametrize("angle", [0.0, 30.0, -120.0])
def test_a_lid_moves_along_itself_however_the_box_is_turned(angle):
    """bodies[].lid_velocity is tangential in the box's own frame: on a box turned by `angle` the lid nodes
    move at |U| along the lid, none across it (an audit: at 30 degrees the lid moved at -0.5 U through itself,
    and a cavity blew up at step 3)."""
    from psph.boundaries.bodies import make_bodies
    from psph.scene.load import load_scene
    from tests.helpers import CASES

    scene = load_scene(CASES / "lid_driven_cavity.toml", [f"bodies.0.angle={angle}", "domain.lower=[-0.5, -0.5]",
                                                           "domain.upper=[1.5, 1.5]", "domain.periodic=[false, false]"])
    body = make_bodies(scene)[0]
    _, normals, vel = body.nodes(0.0)
    lid = body.lid
    assert lid.sum() > 10 and not np.any(vel[~lid])
    turned = np.deg2rad(angle)
    assert np.allclose(normals[lid], [-np.sin(turned), np.cos(turned)], atol=1e-12) or \
        np.allclose(normals[lid], [np.sin(turned), -np.cos(turned)], atol=1e-12)
    assert np.abs(np.sum(vel[lid] * normals[lid], axis=1)).max() < 1e-12
    assert np.allclose(np.linalg.norm(vel[lid], axis=1), np.linalg.norm(scene.bodies[0].lid_velocity), rtol=1e-12)
