"""Polygons (`shape = "polygon"`): as containers (a tank of any straight-sided shape), the profile, the
scene's refusals by key, a polygon drawn on a box's corners running as the box, and seed 002's trapezoidal
tank holding water at rest; as immersed bodies (`fluid = "outside"`, seed 004's triangular cylinder), the
profile and centroid, a polygon on SPHERIC 6's square running as the rectangle, the escape check and the
refusals."""

import numpy as np
import pytest
from mpi4py import MPI

from psph.boundaries.bodies import Body
from psph.boundaries.geometry import (
    distance_to_polygon,
    inside,
    polygon_centroid,
    polygon_profile,
    rectangle_profile,
    sharp_corner_points,
)
from psph.drivers.fluid import FluidDriver
from psph.errors import SceneError
from psph.io.history import read_history
from psph.particles import Kind
from psph.scene.load import load_scene
from tests.helpers import CASES

SQUARE = [[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]]
TRAPEZOID = CASES / "trapezoidal_tank.toml"


def PARTITIONED(width):  # noqa: N802 (a table of corners)
    """The trapezoidal tank's corners with a partition `width` thick rising 0.9 from its floor at x = 0.7
    (clockwise if width < 0)."""
    corners = [[0.0, 0.0], [0.7, 0.0], [0.7, 0.9], [0.7 + abs(width), 0.9], [0.7 + abs(width), 0.0], [1.0, 0.0],
               [1.6, 1.2], [0.0, 1.2]]
    return corners[:1] + corners[1:][::-1] if width < 0 else corners


@pytest.mark.parametrize("order", [1, -1])
def test_the_profile_is_the_same_in_either_sense_with_normals_out_of_the_fluid(order):
    corners = SQUARE if order == 1 else SQUARE[::-1]
    profile = polygon_profile(corners, 0.1)
    assert profile.fluid_inside
    as_rectangle = rectangle_profile([1.0, 0.5], [2.0, 1.0], 0.0, 0.1, fluid_inside=True)
    # the same nodes and normals as the box's (which start at its lower-left corner)
    start = int(np.flatnonzero(np.all(np.isclose(profile.nodes, [0.0, 0.0]), axis=1))[0])
    nodes, normals = np.roll(profile.nodes, -start, axis=0), np.roll(profile.normals, -start, axis=0)
    assert np.allclose(nodes, as_rectangle.nodes, atol=1e-14) and np.allclose(normals, as_rectangle.normals)
    on_bottom = np.isclose(nodes[:, 1], 0.0) & (nodes[:, 0] > 0.0) & (nodes[:, 0] < 2.0)
    assert np.allclose(normals[on_bottom], [0.0, -1.0])
    assert np.allclose(normals[0], [-np.sqrt(0.5), -np.sqrt(0.5)])  # a corner: the bisector


def test_inside_and_distance_to_an_inclined_side():
    trapezoid = [[0.0, 0.0], [1.0, 0.0], [1.6, 1.2], [0.0, 1.2]]
    points = np.array([[0.5, 0.5], [1.3, 0.4], [1.2, 0.4], [-0.1, 0.5]])
    assert inside(("polygon", trapezoid, None, 0.0), points).tolist() == [True, False, True, False]
    # the inclined side rises 2 per 1: distance |2 (x - 1) - y| / sqrt(5)
    expected = [0.5, abs(2 * 0.3 - 0.4) / np.sqrt(5.0), abs(2 * 0.2 - 0.4) / np.sqrt(5.0), 0.1]
    assert np.allclose(distance_to_polygon(trapezoid, points), expected)


def test_a_polygon_on_a_box_corners_runs_as_the_box(tmp_path):
    """The hydrostatic tank with its box given as a polygon of the same corners: the same particles, and
    the same run bit for bit."""
    base = ["domain.dx=0.1", "time.t_end=0.3", "output.every=0", "output.history_every=1"]
    box = load_scene(CASES / "hydrostatic_tank.toml", base)
    polygon = load_scene(CASES / "hydrostatic_tank.toml", [*base, "bodies.0.shape=polygon", "bodies.0.center=[]",
                                                           "bodies.0.size=[]", "bodies.0.vertices=[[0.0, 0.0], "
                                                           "[2.0, 0.0], [2.0, 1.2], [0.0, 1.2]]"])
    runs = {}
    for name, scene in (("box", box), ("polygon", polygon)):
        driver = FluidDriver(scene, MPI.COMM_SELF, tmp_path / name)
        runs[name] = driver.run()
    assert runs["box"]["n_particles"] == runs["polygon"]["n_particles"]
    a, b = (read_history(tmp_path / name / "history.csv") for name in ("box", "polygon"))
    assert len(a) == len(b) > 3
    for ra, rb in zip(a, b):  # (NaN, the forces before any right-hand side, as NaN)
        assert {k: str(v) for k, v in ra.items() if not k.endswith("_s")} == \
            {k: str(v) for k, v in rb.items() if not k.endswith("_s")}


def test_the_trapezoidal_tank_fills_the_lattice_and_holds_water_at_rest(tmp_path):
    """H/dx = 10 to t sqrt(g/H) = 2: the clone walls' solids complete the fluid's lattice along the
    inclined wall (grad Gamma is round-off, so the packing has nothing to do), the water stays at rest,
    its pressure hydrostatic (at H/dx = 25 and 50: docs/results.md, Walls), and its weight on the tank."""
    scene = load_scene(TRAPEZOID, ["domain.dx=0.1", "time.t_end=2.0", "output.every=0", "output.history_every=10",
                                   "packing.iterations=20"])
    driver = FluidDriver(scene, MPI.COMM_SELF, tmp_path)
    summary = driver.run()
    assert summary["packing"]["Linf_grad_gamma_start"] < 1e-12
    p = driver.system.particles
    kind, pos = p.owned("kind"), p.owned("position")
    fluid = kind == Kind.FLUID
    assert np.all(2.0 * (pos[fluid, 0] - 1.0) < pos[fluid, 1])  # every fluid particle left of the inclined wall
    cells = (np.arange(16) + 0.5) * 0.1
    x, y = np.meshgrid(cells, cells[:10], indexing="ij")  # the lattice points inside the trapezoid below y = 1
    assert np.count_nonzero(fluid) == np.count_nonzero(x < 1.0 + y / 2.0) == 125
    history = read_history(tmp_path / "history.csv")
    # no load measured before the first step: not 0.0, which read as a tank carrying nothing (a diagnostics audit)
    assert np.isnan(history[0]["force_y_tank"]) and np.isnan(history[0]["force_x_tank"])
    rows = [r for r in history if r["time"] >= 1.0]
    assert max(r["max_speed"] for r in rows) < 5e-3  # in sqrt(g H); 1e-3 at H/dx = 25
    weight = rows[-1]["total_mass"]  # g = 1: the walls carry the water's weight, and no net sideways push
    for r in rows:
        assert abs(r["force_y_tank"] / weight + 1.0) < 0.02 and abs(r["force_x_tank"]) < 0.01 * weight
    error = p.owned("pressure")[fluid] - (1.0 - pos[fluid, 1])
    assert np.sqrt(np.mean(error**2)) < 0.03  # in rho0 g H


@pytest.mark.parametrize("sets,key,words", [
    (["bodies.0.vertices=[[0.0, 0.0], [1.0, 0.0]]"], "bodies[0].vertices", "at least 3 corners, got 2"),
    (["bodies.0.vertices=[[0.0, 0.0], [1.6, 1.2], [1.0, 0.0], [0.0, 0.8]]"], "bodies[0].vertices",
     "side 0 (corners 0-1) crosses side 2 (corners 2-3): the polygon must be simple"),
    (["bodies.0.vertices=[[0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [0.0, 1.2]]"], "bodies[0].vertices[1]",
     "repeats corner 0"),
    (["bodies.0.vertices=[[0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.2]]"], "bodies[0].vertices[1]",
     "expected 2 entries [x, y], got 3"),
    (["bodies.0.vertices=[[0.0, 0.0], [2.0, 0.0], [1.6, 1.2], [0.0, 1.2]]"], "bodies[0].vertices",
     "leaves the domain along axis 0"),
    (["bodies.0.center=[0.8, 0.6]"], "bodies[0].center", "a polygon is given by its corners"),
    (["bodies.0.angle=10.0"], "bodies[0].angle", "turn them instead"),
    (["bodies.0.motion.law=constant", "bodies.0.motion.velocity=[1.0, 0.0]"], "bodies[0].motion.law",
     "a polygon (the fluid's container) stays fixed"),
    (["bodies.0.model=ghost"], "bodies[0].model", "an axis-aligned box"),
    (["bodies.0.vertices=[[0.0, 0.0], [1.2, 1.2], [0.6, 0.6]]"], "bodies[0].vertices", "enclose no area"),
    (["bodies.0.vertices=[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [1.0, 0.5], [0.0, 1.0]]"], "bodies[0].vertices[2]",
     "folds back on itself"),
    (["domain.periodic=[true, false]"], "bodies[0].shape", "a periodic axis does not allow"),
    # a partition 1.5 dx thick between two basins (a failure audit: 0.8 dx let fluid through, exit 0)
    ([f"bodies.0.vertices={PARTITIONED(0.15)}"], "bodies[0].vertices",
     "the wall of 'tank' between its sides 1 ([0.7, 0.0] to [0.7, 0.9]) and 3 is 0.15 thick at (0.7, 0.1), less "
     "than 2 dx = 0.2: no solid particle would fill it, and the fluid would cross it"),
    ([f"bodies.0.vertices={PARTITIONED(-0.15)}"], "bodies[0].vertices",
     "between its sides 4 ([0.85, 0.0] to [0.85, 0.9]) and 6 is 0.15 thick at (0.85, 0.1)"),
])
def test_bad_polygons_are_refused_by_key(sets, key, words):
    load_scene(TRAPEZOID, ["domain.dx=0.1", f"bodies.0.vertices={PARTITIONED(0.2)}"])  # 2 dx: admitted
    # the solid coming to a point is no partition: a 45-degree ramp ending in a vertical drop (a review: refused
    # at any dx, though it holds water at rest)
    load_scene(TRAPEZOID, ["domain.dx=0.02", "bodies.0.vertices=[[0.0, 0.0], [0.6, 0.0], [1.0, 0.4], [1.0, 0.0], "
                                             "[1.6, 0.0], [1.6, 1.2], [0.0, 1.2]]"])
    load_scene(TRAPEZOID, ["domain.dx=0.1"])
    with pytest.raises(SceneError) as info:
        load_scene(TRAPEZOID, ["domain.dx=0.1", *sets])
    assert info.value.key == key and words in str(info.value)


@pytest.mark.parametrize("sets,key,words", [
    (["bodies.0.size=[]"], "bodies[0].size", "expected 2 entries, got 0"),
    (["bodies.0.vertices=[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]"], "bodies[0].vertices",
     "corners define a polygon, not a box"),
])
def test_a_box_needs_its_size_and_no_corners(sets, key, words):
    with pytest.raises(SceneError) as info:
        load_scene(CASES / "hydrostatic_tank.toml", sets)
    assert info.value.key == key and words in str(info.value)


# immersed polygons (fluid = "outside"): seed 004's triangular cylinder
TRIANGLE = CASES / "triangular_cylinder.toml"
SQUARE_BODY = ["bodies.1.shape=polygon", "bodies.1.center=[]", "bodies.1.size=[]", "bodies.1.fluid=outside",
               "bodies.1.vertices=[[1.0, 2.0], [2.0, 2.0], [2.0, 3.0], [1.0, 3.0]]"]


def test_an_immersed_polygon_has_the_normals_into_it_and_turns_about_its_area_centroid():
    profile = polygon_profile(SQUARE[::-1], 0.1, fluid_inside=False)
    assert not profile.fluid_inside
    as_rectangle = rectangle_profile([1.0, 0.5], [2.0, 1.0], 0.0, 0.1, fluid_inside=False)
    start = int(np.flatnonzero(np.all(np.isclose(profile.nodes, [0.0, 0.0]), axis=1))[0])
    assert np.allclose(np.roll(profile.nodes, -start, axis=0), as_rectangle.nodes, atol=1e-14)
    assert np.allclose(np.roll(profile.normals, -start, axis=0), as_rectangle.normals)
    assert np.allclose(profile.normals[start], [np.sqrt(0.5), np.sqrt(0.5)])  # the lower-left corner, inwards
    # an L of two unit squares and one more on top of the left one: centroid (5/6, 5/6), not the corners' mean
    ell = [[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0], [1.0, 2.0], [0.0, 2.0]]
    assert np.allclose(polygon_centroid(ell), [5.0 / 6.0, 5.0 / 6.0])
    assert not np.allclose(np.mean(ell, axis=0), [5.0 / 6.0, 5.0 / 6.0])
    assert np.allclose(polygon_centroid(ell[::-1]), [5.0 / 6.0, 5.0 / 6.0])
    scene = load_scene(CASES / "moving_square.toml", [*SQUARE_BODY[:-1], "bodies.1.vertices=" + str(
        [[1.0 + x, 2.0 + y] for x, y in np.array(ell) / 2.0])])
    body = Body(scene.bodies[1], 1, scene.domain.dx, (1.0, 0.0))
    assert np.allclose(body.center0, [1.0 + 5.0 / 12.0, 2.0 + 5.0 / 12.0]) and body.kind == Kind.BODY


def test_a_corner_sharper_than_90_degrees_gets_a_solid_particle_in_its_tip():
    """The lattice fills a 60-degree corner only from 1.2-1.8 dx behind it; geometry.sharp_corner_points puts
    one solid dx/2 from both sides, on the bisector. None at a right angle or wider; on a container, at a
    corner of its solid (a weir's crest)."""
    dx = 0.1
    triangle = [[-0.5773502691896258, 0.0], [0.2886751345948129, -0.5], [0.2886751345948129, 0.5]]
    for corners in (triangle, triangle[::-1]):
        tips = sharp_corner_points(corners, False, dx)[0]
        assert len(tips) == 3 and np.all(inside(("polygon", corners, None, 0.0), tips))
        assert np.allclose(distance_to_polygon(corners, tips), dx / 2)
        assert np.allclose(np.sort(np.hypot(*(tips - np.array(triangle)[:, None]).transpose(2, 0, 1)).min(axis=1)),
                           dx)  # dx/2 / sin(30 degrees) from each corner
    assert len(sharp_corner_points(SQUARE, False, dx)[0]) == len(sharp_corner_points(SQUARE, True, dx)[0]) == 0
    assert len(sharp_corner_points(triangle, True, dx)[0]) == 0  # a triangular tank: its solid is wide at every corner
    weir = [[0.0, 0.0], [0.6, 0.0], [1.0, 0.4], [1.0, 0.0], [1.6, 0.0], [1.6, 1.2], [0.0, 1.2]]
    crest = sharp_corner_points(weir, True, dx)[0]  # the 45-degree solid under the ramp's top
    assert crest.shape == (1, 2) and not inside(("polygon", weir, None, 0.0), crest)[0]
    assert np.allclose(distance_to_polygon(weir, crest), dx / 2) and crest[0, 0] < 1.0
    scene = load_scene(TRIANGLE)
    body = Body(scene.bodies[2], 2, dx, (1.0, 0.0))
    lattice = np.stack(np.meshgrid(np.arange(-0.95, 1.0, dx), np.arange(-0.95, 1.0, dx)), axis=-1).reshape(-1, 2)
    pos, normal, dist, node, vol = body.solid_particles(lattice, np.full(len(lattice), dx * dx), 0.4)
    tips, corners = sharp_corner_points(triangle, False, dx)
    assert np.allclose(pos[-3:], tips) and np.allclose(dist[-3:], dx / 2)
    assert np.allclose(vol, dx * dx) and np.allclose(np.linalg.norm(normal, axis=1), 1.0)
    # each with its corner's normal, along the bisector into the body (the nearest node is beside the corner)
    assert np.allclose(normal[-3:], (tips - corners) / np.linalg.norm(tips - corners, axis=1)[:, None])


@pytest.mark.parametrize("turning", [[], ["bodies.1.motion.rotation_law=oscillate",
                                           "bodies.1.motion.angular_velocity=1.0", "bodies.1.motion.period=0.5"]])
def test_an_immersed_polygon_on_a_rectangle_s_corners_runs_as_the_rectangle(tmp_path, turning):
    """SPHERIC 6's square, accelerated by the benchmark's law (and rocking about its centre), given as a
    polygon with the fluid outside: the same particles, and the same run (drag and moment included) bit for
    bit."""
    base = ["domain.dx=0.1", "time.t_end=0.3", "output.every=0", "output.history_every=1",
            "shifting.method=delta_plus", "iips.update=none", *turning]
    runs, histories = {}, {}
    for name, sets in (("rectangle", base), ("polygon", [*base, *SQUARE_BODY])):
        scene = load_scene(CASES / "moving_square.toml", sets)
        runs[name] = FluidDriver(scene, MPI.COMM_SELF, tmp_path / name).run()
        histories[name] = read_history(tmp_path / name / "history.csv")
    assert runs["rectangle"]["n_particles"] == runs["polygon"]["n_particles"]
    a, b = histories["rectangle"], histories["polygon"]
    assert len(a) == len(b) > 50 and abs(a[-1]["cd_pressure"]) > 0.5  # it moved, and pushed the fluid
    for ra, rb in zip(a, b):
        assert {k: str(v) for k, v in ra.items() if not k.endswith("_s")} == \
            {k: str(v) for k, v in rb.items() if not k.endswith("_s")}


def test_a_fluid_particle_inside_an_immersed_polygon_is_named():
    """The run's escape check (WallTerms.trespassers): more than `margin` inside the triangle, in its
    reference configuration; the lowest gid of several."""
    from psph.boundaries.clone import WallTerms

    walls = WallTerms(load_scene(TRIANGLE))
    pos = np.array([[-3.0, 0.0], [0.0, 0.0], [0.25, 0.45], [-0.1, 0.0]])  # out, in, 0.03 in, in
    assert walls.trespassers(pos, 0.0, 0.05, np.array([7, 9, 3, 8])) == (3, "triangle")
    assert walls.trespassers(pos[[0, 2]], 0.0, 0.05, np.array([7, 3])) is None
    moving = WallTerms(load_scene(CASES / "moving_square.toml", SQUARE_BODY))
    c = moving.bodies[1].rigid(2.0)[0]  # at t = 2 the square has moved on: its old place is fluid
    assert moving.trespassers(np.array([[1.5, 2.5], c]), 2.0, 0.05, np.array([1, 2]))[0] == 1


@pytest.mark.parametrize("sets,key,words", [
    # the triangle as a container: the plates would lie outside its fluid
    (["bodies.2.fluid=inside"], "bodies[0].center", "'bottom' comes within dx of the walls of bodies[2] ('triangle')"),
    (["bodies.0.fluid=outside"], "bodies[0].fluid", "a rectangle has the fluid outside: fluid is a polygon's key"),
    (["bodies.2.vertices=[[0.0, 0.0], [1.0, 0.0], [1.0, 0.15], [0.0, 0.15]]"], "bodies[2].vertices",
     "is 0.15 thick, less than 2 dx = 0.2"),
    # a plate bent into a V: its bounding box is wide, its arms 0.15 thick
    (["bodies.2.vertices=[[-1.0, 1.0], [0.0, 0.0], [1.0, 1.0], [1.0, 1.15], [0.0, 0.15], [-1.0, 1.15]]"],
     "bodies[2].vertices", "less than 2 dx = 0.2: no solid particle would fill it, and the fluid would cross it"),
    (["bodies.2.vertices=[[-7.5, -0.5], [-6.5, 0.0], [-7.5, 0.5]]"], "bodies[2].vertices",
     "'triangle' leaves the domain along axis 0"),
    # (the plate's side is the first found: either body is where it was given)
    (["bodies.2.vertices=[[-0.5, 3.3], [0.5, 3.3], [0.0, 3.95]]"], "bodies[1].center",
     "'top' comes within dx of bodies[2] ('triangle') at t = 0"),
])
def test_bad_immersed_polygons_are_refused_by_key(sets, key, words):
    load_scene(TRIANGLE, ["domain.dx=0.1", "bodies.2.motion.law=constant", "bodies.2.motion.velocity=[0.1, 0.0]",
                          "time.t_end=1"])  # an immersed polygon may move
    with pytest.raises(SceneError) as info:
        load_scene(TRIANGLE, ["domain.dx=0.1", *sets])
    assert info.value.key == key and words in str(info.value)
