"""Scene validation: every bad input is a SceneError naming its key path; overrides; frozen results."""

import dataclasses
import math

import pytest

from psph.errors import SceneError, UsageError
from psph.scene.load import apply_overrides, load_scene, parse_override, read_table, scene_from_table
from psph.scene.schema import Scene
from psph.scene.validate import describe_keys
from psph.studies import CAVITY_WALLS
from tests.helpers import CASES


def base():
    return {"name": "t", "domain": {"dimension": 2, "lower": [0.0, 0.0], "upper": [1.0, 1.0],
                                    "periodic": [True, True], "dx": 0.05}}


def with_value(path, value):
    table = base()
    node = table
    parts = path.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = value
    return table


def test_minimal_scene_gets_defaults():
    s = scene_from_table(base())
    assert s.domain.h_over_dx == 2.0 and s.domain.kernel == "wendland_c6"
    assert s.physics.scheme == "none" and s.shifting.method == "none"
    assert math.isclose(s.domain.h, 0.1) and s.domain.lattice_shape() == (20, 20)
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.domain.dx = 1.0


@pytest.mark.parametrize("path,value,key,words", [
    ("domain.dx", -0.1, "domain.dx", "must be > 0"),
    ("domain.dx", "fine", "domain.dx", "expected number"),
    ("domain.dx", float("nan"), "domain.dx", "finite"),
    ("domain.dx", float("inf"), "domain.dx", "finite"),
    ("domain.dx", 0.03, "domain.dx", "must divide"),
    ("domain.dx", 0.25, "domain.dx", "longer than the kernel support"),
    ("domain.dimension", 4, "domain.dimension", "not one of"),
    ("domain.dimension", True, "domain.dimension", "expected integer"),
    ("domain.periodic", [True, 1], "domain.periodic[1]", "expected boolean"),
    ("domain.upper", [1.0], "domain.upper", "expected 2 entries (dimension = 2)"),
    ("domain.upper", [1.0, -1.0], "domain.upper[1]", "must exceed"),
    ("domain.upper", 1.0, "domain.upper", "expected array of number"),
    ("domain.kernel", "gauss", "domain.kernel", "not one of"),
    ("domain.h_over_dx", 9.0, "domain.h_over_dx", "<= 4.0"),
    ("domain.colour", "red", "domain.colour", "unknown key"),
    ("initial.sigma_over_dx", -0.1, "initial.sigma_over_dx", ">= 0.0"),
    ("initial.seed", -3, "initial.seed", ">= 0"),
    ("initial.seed", 2**64, "initial.seed", "< 9223372036854775808"),
    ("shifting.method", "magic", "shifting.method", "not one of"),
    ("shifting.delta_plus_n", 3000.0, "shifting.delta_plus_n", "<= 16.0"),  # overflowed to NaN positions
    ("shifting", 3, "shifting", "expected a table"),
    ("physics.scheme", {"deep": {"deeper": 1}}, "physics.scheme", "expected string"),
    ("diagnostics.test_wavelength", 0.3, "diagnostics.test_wavelength", "must divide"),
    ("extra", {}, "extra", "unknown key"),
    ("physics.free_stream", [1.0, 0.0], "physics.free_stream", "needs a fluid scheme"),
    ("physics.free_stream", [1.0], "physics.free_stream", "expected 2 entries"),
    ("physics.muscl_limiter", "none", "physics.muscl_limiter", "belong to physics.scheme = riemann_ale"),
    ("physics.riemann_dissipation", "low", "physics.riemann_dissipation", "belong to physics.scheme = riemann_ale"),
    ("physics.muscl_limiter", "superbee", "physics.muscl_limiter", "not one of"),
    ("iips.update", "nfts", "iips.update", 'physics.scheme = \'none\', not a fluid scheme (set iips.update = "none")'),
    ("iips.pre_newton", 5, "iips.pre_newton", "a static run is itself the pre-procedure"),
    # rho0 c0^2 overflowed in the equation of state (OverflowError: a traceback called a bug)
    ("physics.sound_speed", 1e160, "physics.sound_speed", "rho0 c0^2 = 10^320 is beyond floating point"),
])
def test_bad_values_name_their_key(path, value, key, words):
    with pytest.raises(SceneError) as info:
        scene_from_table(with_value(path, value))
    assert info.value.key == key
    assert words in str(info.value)
    assert "\n" not in str(info.value)


def test_missing_required_keys():
    table = base()
    del table["domain"]["dx"]
    with pytest.raises(SceneError, match="domain.dx: required key missing"):
        scene_from_table(table)
    with pytest.raises(SceneError, match="name: required key missing"):
        scene_from_table({"domain": base()["domain"]})


def test_overrides_parse_toml_literals_and_bare_words():
    assert parse_override("domain.dx=0.0125") == (["domain", "dx"], 0.0125)
    assert parse_override("shifting.method=iips") == (["shifting", "method"], "iips")
    assert parse_override('name="a b"') == (["name"], "a b")
    assert parse_override("domain.periodic=[true, false]") == (["domain", "periodic"], [True, False])
    for bad in ("novalue", "=3", "a..b=1", "a.b c=1"):
        with pytest.raises(UsageError):
            parse_override(bad)
    table = apply_overrides(base(), ["initial.seed=5", "domain.dx=0.025"])
    assert table["initial"]["seed"] == 5 and table["domain"]["dx"] == 0.025
    assert base()["domain"]["dx"] == 0.05  # the original is untouched
    with pytest.raises(SceneError, match="is a value"):
        apply_overrides(base(), ["name.sub=1"])


def test_reading_files(tmp_path):
    good = tmp_path / "s.toml"
    good.write_text('name = "x"\n[domain]\ndimension = 1\nlower = [0.0]\nupper = [1.0]\n'
                    'periodic = [true]\ndx = 0.01\n')
    assert load_scene(good, ["domain.dx=0.02"]).domain.dx == 0.02
    with pytest.raises(UsageError, match="not found"):
        read_table(tmp_path / "missing.toml")
    broken = tmp_path / "b.toml"
    broken.write_text("name = \n")
    with pytest.raises(SceneError, match="not valid TOML"):
        read_table(broken)
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(SceneError, match="not UTF-8"):
        read_table(binary)
    deep = tmp_path / "deep.toml"
    deep.write_text("x = " + "[" * 100000 + "]" * 100000 + "\n")
    with pytest.raises(SceneError):
        load_scene(deep)


def test_every_key_is_documented():
    rows = describe_keys(Scene)
    assert all(doc for _, _, _, doc in rows)
    keys = {k for k, _, _, _ in rows}
    assert {"domain.dx", "time.t_end", "output.every", "shifting.method", "initial.sigma_over_dx",
            "initial.seed", "bodies[].vertices", "bodies[].motion.law", "inflow[].velocity"} <= keys


def ghost_cavity(**changes):
    """The lid-driven cavity's table with seed 001's ghost walls and delta+, and `changes` as key path -> value."""
    table = apply_overrides(read_table(CASES / "lid_driven_cavity.toml"), CAVITY_WALLS["ghost"])
    for path, value in changes.items():
        node = table
        *parents, last = path.split(".")
        for part in parents:
            node = node[int(part)] if isinstance(node, list) else node[part]
        node[last] = value
    return table


@pytest.mark.parametrize("changes,key,words", [
    ({"bodies.0.shape": "rectangle", "bodies.0.lid_velocity": []}, "bodies[0].model", "axis-aligned box"),
    ({"bodies.0.angle": 10.0}, "bodies[0].model", "axis-aligned box"),
    ({"shifting.method": "iips"}, "bodies[0].model", "needs clone walls"),
    ({"shifting.method": "neuhauser"}, "bodies[0].model", "needs clone walls"),
    ({"physics.scheme": "none"}, "bodies[0].model", "need a fluid scheme"),
    ({"domain.periodic": [True, False], "bodies.0.size": [0.8, 1.0]}, "bodies[0].model", "must span the domain"),
    ({"bodies.0.size": [1.0, 0.05], "bodies.0.center": [0.5, 0.95]}, "bodies[0].model", "too narrow"),
    ({"bodies.0.size": [1.2, 1.0]}, "bodies[0].model", "leaves the domain"),
])
def test_ghost_walls_are_refused_where_they_do_not_apply(changes, key, words):
    scene_from_table(ghost_cavity())  # the cavity itself is fine
    with pytest.raises(SceneError) as info:
        scene_from_table(ghost_cavity(**changes))
    assert info.value.key == key and words in str(info.value)


@pytest.mark.parametrize("model", ["clone", "ghost"])
def test_riemann_ale_takes_walls_and_says_how(model):
    """The Riemann SPH-ALE scheme takes both wall models (the Riemann problem against the mirrored solids,
    psph.compute.walls) and its description names them."""
    from psph.schemes import make_scheme

    scene = scene_from_table(ghost_cavity(**{"bodies.0.model": model, "physics.scheme": "riemann_ale"}))
    lines = make_scheme(scene).describe()
    assert any("partial Riemann problem" in line for line in lines)
    assert any(("clone particles" if model == "clone" else "fixed ghost particles") in line for line in lines)


@pytest.mark.parametrize("scheme, key, accepted", [
    ("riemann_ale", "delta", False), ("riemann_ale", "delta_m", False), ("delta_ale_const_mass", "delta_m", False),
    ("delta_ale_const_volume", "delta_m", False), ("delta_ale_const_mass", "delta", True),
    ("delta_ale", "delta_m", True)])
def test_a_diffusion_coefficient_the_scheme_does_not_read_is_refused(scheme, key, accepted):
    """A Riemann audit: physics.delta = 0.3 with riemann_ale ran, and psph info showed it, to no effect."""
    sets = [f"physics.scheme={scheme}", f"physics.{key}=0.3"]
    if accepted:
        assert getattr(load_scene(CASES / "taylor_green.toml", sets).physics, key) == 0.3
        return
    with pytest.raises(SceneError) as info:
        load_scene(CASES / "taylor_green.toml", sets)
    assert info.value.key == f"physics.{key}" and "diffusion to scale" in str(info.value)


@pytest.mark.parametrize("model", ["clone", "ghost"])
def test_a_lid_on_a_periodic_y_axis_is_refused(model):
    changes = {"domain.periodic": [False, True], "bodies.0.model": model}
    for size in ([1.0, 1.0], [1.0, 1.2]):  # the top side on the domain's end, or beyond it
        with pytest.raises(SceneError) as info:
            scene_from_table(ghost_cavity(**changes, **{"bodies.0.size": size}))
        assert info.value.key == "bodies[0].lid_velocity" and "lid would be ignored" in str(info.value)
    changes["bodies.0.lid_velocity"] = []
    scene_from_table(ghost_cavity(**changes))  # without a lid, a channel


@pytest.mark.parametrize("sets,key,words", [
    (["bodies.1.motion.law=fixed"], "bodies[1].motion.velocity", "a fixed body does not move"),
    (["bodies.1.size=[0.1, 1.0]"], "bodies[1].size", "less than 2 dx"),
    (["bodies.1.center=[9.8, 2.5]", "bodies.1.motion.law=fixed", "bodies.1.motion.velocity=[]"],
     "bodies[1].center", "leaves the domain along axis 0"),
    (["bodies.1.center=[1.5, 0.55]"], "bodies[1].center", "within dx of the walls of bodies[0]"),
    # driven into a wall by its motion: the motion is named
    (["time.t_end=9.0"], "bodies[1].motion", "within dx of the walls of bodies[0] ('tank') at t = 8."),
    (["bodies.1.motion.velocity=[0.0, 1.0]"], "bodies[1].motion", "within dx of the walls"),
    (["bodies.0.size=[10.5, 5.0]"], "bodies[0].size", "leaves the domain along axis 0: the fluid"),
    # a container that would fit, placed out: its centre is named (the size was, whichever was given)
    (["bodies.0.center=[5.0, 2.6]"], "bodies[0].center", "leaves the domain along axis 1: the fluid"),
    (["bodies.1.size=[1e12, 1.0]"], "bodies[1].center", "leaves the domain along axis 0"),
    # a huge velocity (once an OverflowError in the motion's sampling): refused before it is sampled
    (["bodies.1.motion.velocity=[1e300, 0.0]"], "bodies[1].motion.velocity", "not below the speed of sound"),
    (["bodies.1.motion.velocity=[1e308, 1e308]"], "bodies[1].motion.velocity", "not below the speed of sound"),
    # a velocity of the wrong length beside a rotation (once a ValueError in the motion)
    (["bodies.1.motion.velocity=[1.0, 0.0, 0.0]", "bodies.1.motion.angular_velocity=1.0"],
     "bodies[1].motion.velocity", "give 2 entries, got 3"),
    (["bodies.1.motion.velocity=[1.0]", "bodies.1.motion.angular_velocity=1.0"],
     "bodies[1].motion.velocity", "give 2 entries, got 1"),
    (["bodies.1.motion.velocity=[0.0, 0.0]"], "bodies[1].motion.velocity", "by law 'spheric6' needs a non-zero"),
    (["bodies.0.lid_velocity=[0.0, 1.0]"], "bodies[0].lid_velocity", "must be 0"),
    (["bodies.0.lid_velocity=[1.0, 0.0, 0.0]"], "bodies[0].lid_velocity", "expected 2 entries, got 3"),
    # (a new user's audit: a rectangle's lid was told "give 2 entries", which it had)
    (["bodies.1.lid_velocity=[1.0, 0.0]"], "bodies[1].lid_velocity", "top side of a box (the fluid inside), not of "
                                                                      "a rectangle"),
    # the rotation's own law
    (["bodies.1.motion.rotation_law=ramp"], "bodies[1].motion.angular_velocity", "by rotation_law 'ramp' needs"),
    (["bodies.1.motion.law=fixed", "bodies.1.motion.velocity=[]", "bodies.1.motion.angular_velocity=1.0"],
     "bodies[1].motion.angular_velocity", "the rotation's law is fixed: give motion.law or motion.rotation_law"),
    (["bodies.1.motion.rotation_law=fixed", "bodies.1.motion.angular_velocity=1.0"],
     "bodies[1].motion.angular_velocity", "the rotation's law is fixed: give motion.rotation_law"),
    (["bodies.0.motion.rotation_law=oscillate", "bodies.0.motion.angular_velocity=1.0"],
     "bodies[0].motion.rotation_law", "a box (the fluid's container) stays fixed"),
    (["bodies.1.motion.law=oscillate", "bodies.1.motion.velocity=[-1.0, 0.0]", "bodies.1.motion.period=10.0"],
     "bodies[1].motion",
     "within dx of the walls of bodies[0]"),
    (["bodies.1.name=' '"], "bodies[1].name", "give the body a name"),
    # faster than sound: the run stopped at step 1 naming the body's own particle, 'the flow is blowing up'
    (["time.t_end=0.05", "bodies.1.motion.law=constant", "bodies.1.motion.velocity=[20.0, 0.0]"],
     "bodies[1].motion.velocity", "would move at 20, not below the speed of sound physics.sound_speed = 12"),
    (["time.t_end=0.05", "bodies.1.motion.law=constant", "bodies.1.motion.velocity=[0.0, 0.0]",
      "bodies.1.motion.angular_velocity=20.0"], "bodies[1].motion.angular_velocity",
     "would move at 14.1421, not below the speed of sound"),
    (["time.t_end=0.05", "physics.sound_speed=1.0"], "bodies[1].motion.velocity", "would move at 1, not below"),
    # a translation law with nothing to translate beside the rotation's own law
    (["bodies.1.motion.law=constant", "bodies.1.motion.velocity=[0.0, 0.0]", "bodies.1.motion.rotation_law=ramp",
      "bodies.1.motion.angular_velocity=0.1"], "bodies[1].motion.velocity", "needs a non-zero velocity (2 entries)"),
    (["bodies.1.motion.law=oscillate", "bodies.1.motion.period=0.01"], "bodies[1].motion.period",
     "shorter than 20 time steps"),
    (["bodies.1.motion.law=fixed", "bodies.1.motion.velocity=[]", "bodies.1.motion.rotation_law=oscillate",
      "bodies.1.motion.angular_velocity=1.0", "bodies.1.motion.period=1e-300"], "bodies[1].motion.period",
     "shorter than 20 time steps"),
])
def test_misplaced_bodies_are_refused_by_key(sets, key, words):
    """The moving square (dx = 0.1) with one change each: a body that would be built wrongly or driven into
    a wall before t_end is refused at load time, naming the key."""
    load_scene(CASES / "moving_square.toml", ["domain.dx=0.1"])
    with pytest.raises(SceneError) as info:
        load_scene(CASES / "moving_square.toml", ["domain.dx=0.1", *sets])
    assert info.value.key == key and words in str(info.value)


def ellipse_with(*sets, second=None):
    """The inclined ellipse's table (dx = 0.1) with overrides, and optionally a second body (a dict of keys
    replacing the first body's)."""
    table = apply_overrides(read_table(CASES / "inclined_ellipse.toml"), ["domain.dx=0.1", *sets])
    if second is not None:
        table["bodies"].append(dict(table["bodies"][0], name="second", **second))
    return table


@pytest.mark.parametrize("sets,second,key,words", [
    (["bodies.0.center=[13.9, 5.0]"], None, "bodies[0].center", "leaves the domain along axis 0"),
    (["bodies.0.center=[13.3, 5.0]"], None, "bodies[0].center", "within a kernel support, 0.4, of its periodic"),
    (["bodies.0.center=[5.0, 5.0]"], {"center": [5.2, 5.1]}, "bodies[0].center", "overlaps bodies[1]"),
    # a small body inside a larger one, in either order
    (["bodies.0.center=[5.0, 5.0]", "bodies.0.size=[1.0, 0.8]", "bodies.0.angle=0"],
     {"center": [5.0, 5.0], "size": [0.3, 0.2]}, "bodies[1].center", "overlaps bodies[0]"),
    (["bodies.0.center=[5.0, 5.0]", "bodies.0.size=[0.3, 0.2]", "bodies.0.angle=0"],
     {"center": [5.0, 5.0], "size": [1.0, 0.8]}, "bodies[0].center", "overlaps bodies[1]"),
    # a moving body runs into a fixed one: the moving body's motion is named, whichever is listed first (it
    # comes within dx before it overlaps)
    (["bodies.0.center=[5.0, 5.0]"], {"center": [8.0, 5.0], "motion": {"law": "constant", "velocity": [-1.0, 0.0]}},
     "bodies[1].motion", "comes within dx of bodies[1]"),
    (["bodies.0.center=[8.0, 5.0]", "bodies.0.motion.law=constant", "bodies.0.motion.velocity=[-1.0, 0.0]"],
     {"center": [5.0, 5.0], "motion": {}}, "bodies[0].motion", "comes within dx of bodies[1]"),
    # a gap of 0.5 dx holds no fluid particle: the two bodies acted as one (axes 0.5 x 0.2, dx = 0.1)
    (["bodies.0.center=[5.0, 5.0]", "bodies.0.angle=0"], {"center": [6.05, 5.0], "angle": 0.0}, "bodies[0].center",
     "comes within dx of bodies[1]"),
    (["bodies.0.center=[5.0, 5.0]", "bodies.0.angle=0"], {"center": [5.0, 5.45], "angle": 0.0}, "bodies[0].center",
     "comes within dx of bodies[1]"),
])
def test_overlapping_and_wrapping_bodies_are_refused(sets, second, key, words):
    with pytest.raises(SceneError) as info:
        scene_from_table(ellipse_with(*sets, second=second))
    assert info.value.key == key and words in str(info.value)


def test_well_placed_bodies_are_accepted():
    """Two bodies apart, a fixed body with an explicit zero velocity, a turning body far from the walls."""
    scene_from_table(ellipse_with("bodies.0.center=[5.0, 5.0]", second={"center": [8.0, 5.0]}))
    scene_from_table(ellipse_with("bodies.0.center=[5.0, 5.0]", "bodies.0.angle=0",  # a gap of 1.5 dx
                                  second={"center": [6.15, 5.0], "angle": 0.0}))
    scene_from_table(ellipse_with("bodies.0.motion.velocity=[0.0, 0.0]"))
    load_scene(CASES / "moving_square.toml", ["domain.dx=0.1", "bodies.1.center=[5.0, 2.5]",
                                              "bodies.1.motion.law=ramp", "bodies.1.motion.velocity=[]",
                                              "bodies.1.motion.angular_velocity=1.0", "time.t_end=1000"])
    # turning in place by its own law; oscillating across the box for good (amplitude 1 / pi)
    load_scene(CASES / "moving_square.toml", ["domain.dx=0.1", "bodies.1.motion.law=fixed",
                                              "bodies.1.motion.velocity=[]", "bodies.1.motion.rotation_law=oscillate",
                                              "bodies.1.motion.angular_velocity=3.0", "time.t_end=1000"])
    load_scene(CASES / "moving_square.toml", ["domain.dx=0.1", "bodies.1.motion.law=oscillate",
                                              "bodies.1.motion.period=2.0", "time.t_end=1000"])
    # the rotation's law named although it is the translation's, which then moves only the rotation
    load_scene(CASES / "moving_square.toml", ["domain.dx=0.1", "bodies.1.motion.law=ramp",
                                              "bodies.1.motion.velocity=[]", "bodies.1.motion.rotation_law=ramp",
                                              "bodies.1.motion.angular_velocity=1.0"])


def test_set_indexes_arrays_of_tables():
    table = read_table(CASES / "moving_square.toml")
    assert apply_overrides(table, ["bodies.1.motion.law=ramp"])["bodies"][1]["motion"]["law"] == "ramp"
    assert table["bodies"][1]["motion"]["law"] == "spheric6"  # the original is untouched
    for bad, words in (("bodies.2.size=[1, 1]", "is not an index 0-1"), ("bodies.x.size=[1, 1]", "not an index"),
                       ("bodies.1=3", "is an array of tables"), ("bodies.1.center.x=1", "is a value")):
        with pytest.raises(SceneError, match=words):
            apply_overrides(table, [bad])


def test_shifting_with_a_free_surface_needs_clone_walls():
    """The tank's fluid stops at y = 1 in a 1.2 high domain: shifting is accepted (psph detects the surface),
    but not beside ghost walls, which the detection would take for a surface."""
    load_scene(CASES / "hydrostatic_tank.toml", ["shifting.method=iips"])  # (ghost walls refuse iips anyway)
    for sets in (["shifting.method=delta_plus"], ["iips.pre_newton=10"]):
        load_scene(CASES / "hydrostatic_tank.toml", sets)
        with pytest.raises(SceneError) as info:
            load_scene(CASES / "hydrostatic_tank.toml", sets + ["bodies.0.model=ghost"])
        assert info.value.key == "bodies[0].model" and "free surface" in str(info.value)
    load_scene(CASES / "hydrostatic_tank.toml", ["bodies.0.model=ghost"])  # no shifting: no detection


def test_free_surface_thresholds_are_ordered():
    load_scene(CASES / "elliptical_drop.toml", ["free_surface.lambda_interior=0.3"])
    with pytest.raises(SceneError) as info:
        load_scene(CASES / "elliptical_drop.toml", ["free_surface.lambda_interior=0.2"])
    assert info.value.key == "free_surface.lambda_interior" and "lambda_surface" in str(info.value)


def test_a_flow_without_a_skin_is_refused():
    """With neighbours.skin = 0 no stage of a time step could move: refused for flows, kept for static runs
    (whose every move rebuilds the lists)."""
    load_scene(CASES / "static_perturbed.toml", ["neighbours.skin=0.0"])
    with pytest.raises(SceneError) as info:
        load_scene(CASES / "taylor_green.toml", ["neighbours.skin=0.0"])
    assert info.value.key == "neighbours.skin" and "a flow needs a skin" in str(info.value)


@pytest.mark.parametrize("case", sorted(p.name for p in CASES.glob("*.toml")))
def test_every_case_file_is_a_valid_scene(case):
    assert load_scene(CASES / case).name == case.removesuffix(".toml")


@pytest.mark.parametrize("scene,sets,key,words", [
    ("elliptical_drop", ["initial.drop_radius=0"], "initial.velocity", "needs initial.drop_radius"),
    ("elliptical_drop", ["initial.drop_radius=1.4"], "initial.drop_radius", "must clear the domain"),
    ("elliptical_drop", ["initial.drop_radius=0.01"], "initial.drop_radius", "less than 2 dx"),
    ("elliptical_drop", ["initial.fill_upper=[1.0, 1.0]"], "initial.drop_radius", "fills its disc"),
    ("elliptical_drop", ["time.t_end=1.6"], "domain.upper", "stretches to a semi-axis of 3.115"),
    ("elliptical_drop", ["physics.reference_velocity=1e300"], "domain.upper", "semi-axis of at least 1e+300"),
    ("elliptical_drop", ["physics.gravity=[0, -1]"], "physics.gravity", "no gravity"),
    ("elliptical_drop", ["initial.pressure=hydrostatic"], "initial.pressure", "no hydrostatic pressure"),
    ("taylor_green", ["initial.velocity=zero", "shifting.method=none", "iips.update=none",
                      "initial.fill_upper=[1.0, 0.5]", "packing.iterations=10"],
     "packing.iterations", "periodic axis 1"),
    # (a packing audit) the free surface along periodic y is the second one: only the first was checked
    ("taylor_green", ["initial.velocity=zero", "shifting.method=none", "iips.update=none", "packing.iterations=10",
                      "domain.periodic=[false, true]", "initial.fill_lower=[0.25, 0.0]",
                      "initial.fill_upper=[0.75, 0.5]"], "packing.iterations", "periodic axis 1"),
    # a fill reaching two bounded faces with no wall (the packing "diverged" there at any cfl)
    ("taylor_green", ["initial.velocity=zero", "shifting.method=none", "iips.update=none", "packing.iterations=10",
                      "domain.periodic=[false, false]", "initial.fill_upper=[0.5, 0.5]"], "packing.iterations",
     "bounded face(s) x-, y- with no wall"),
    # the cubic spline's pairing instability (the packing stacked particles on each other, and went on)
    ("elliptical_drop", ["domain.kernel=cubic_spline"], "domain.kernel", "pairs particles with the cubic spline"),
    ("static_perturbed", ["domain.dimension=3", "domain.lower=[0, 0, 0]", "domain.upper=[1, 1, 1]",
                          "domain.periodic=[true, true, true]", "domain.dx=0.1", "initial.drop_radius=0.2"],
     "initial.drop_radius", "domain.dimension must be 2"),
    ("static_perturbed", ["packing.iterations=10"], "packing.iterations", "needs a fluid scheme"),
    ("lid_driven_cavity", ["packing.iterations=10", *CAVITY_WALLS["ghost"]], "bodies[0].model", "use clone walls"),
    ("elliptical_drop", ["packing.alpha=0"], "packing.alpha", "must be > 0"),
])
def test_drops_and_packing_are_refused_where_they_do_not_apply(scene, sets, key, words):
    with pytest.raises(SceneError) as info:
        load_scene(CASES / f"{scene}.toml", sets)
    assert info.value.key == key and words in str(info.value), str(info.value)


def test_packing_is_accepted_with_clone_walls_and_a_free_surface():
    for scene in ("lid_driven_cavity", "hydrostatic_tank", "moving_square"):
        assert load_scene(CASES / f"{scene}.toml", ["packing.iterations=10"]).packing.iterations == 10
    assert load_scene(DROP := CASES / "elliptical_drop.toml", ["domain.kernel=cubic_spline", "domain.h_over_dx=1.2"])
    assert load_scene(DROP, ["domain.kernel=cubic_spline", "packing.iterations=0"])


@pytest.mark.parametrize("scene,sets,key,words", [
    ("lid_driven_cavity", ["free_surface.lambda_diffusion=0.2"], "free_surface.lambda_diffusion", "no free surface"),
    ("dam_break", ["physics.scheme=riemann_ale", "bodies=[]"], "free_surface.lambda_diffusion",
     "no diffusive terms: set it to 0"),
    ("dam_break", ["physics.gravity=[0, 1]", "initial.pressure=zero"], "diagnostics.dam_break", "gravity along -y"),
    # a hydrostatic start needs gravity along -y (a fuzzing audit: a zero pressure, or of the wrong sign, else)
    ("dam_break", ["physics.gravity=[0, 1]"], "initial.pressure", "needs gravity along -y"),
    # (a keys audit: the hydrostatic pressure replaced Taylor-Green's analytic one silently)
    ("taylor_green", ["initial.pressure=hydrostatic", "physics.gravity=[0, -1]"], "initial.pressure",
     "comes with its own analytic pressure"),
    ("dam_break", ["physics.gravity=[-1, 0]"], "initial.pressure", "got [-1.0, 0.0] in 2-D"),
    ("hydrostatic_tank", ["domain.dimension=1", "domain.lower=[0.0]", "domain.upper=[1.0]",
                          "domain.periodic=[false]", "bodies=[]", "physics.gravity=[-1.0]", "initial.fill_lower=[0.0]",
                          "initial.fill_upper=[0.5]"],
     "initial.pressure", "needs a y axis: a 2-D or 3-D scene"),  # (a dimensions audit: it offered [0, -g])
    ("dam_break", ["initial.fill_upper=[5.367, 1.0]"], "diagnostics.dam_break", "short of the domain"),
    ("taylor_green", ["diagnostics.dam_break=true"], "diagnostics.dam_break", "gravity along -y"),
    ("dam_break", ["physics.artificial_viscosity=-0.1"], "physics.artificial_viscosity", ">= 0"),
    ("dam_break", ["physics.gravity=[-1.0]", "initial.pressure=zero"], "diagnostics.dam_break", "gravity along -y"),
    ("taylor_green", ["initial.fill_lower=[0.1]"], "initial.fill_lower", "expected 2 entries"),
    ("kinematic_tgv", ["diagnostics.test_wavelength=1e300"], "diagnostics.test_wavelength", "would be constant"),
    ("dam_break", ["initial.fill_upper=[5.36, 1.0]"], "diagnostics.dam_break", "short of the domain"),
    ("dam_break", ["bodies.0.model=ghost"], "bodies[0].model", "shifting with a free surface"),
    ("taylor_green", ["physics.wall_adhesion=true"], "physics.wall_adhesion", "no clone walls"),
    ("lid_driven_cavity", ["physics.wall_adhesion=true"], "physics.wall_adhesion", "no free surface"),
    ("dam_break", ["physics.wall_adhesion=true", "shifting.method=none", "bodies.0.model=ghost"],
     "physics.wall_adhesion", "no clone walls"),
    ("taylor_green", ["initial.fill_lower=[0.8, 0.8]", "initial.fill_upper=[0.2, 0.2]"], "initial.fill_upper",
     "empty along axis 0: upper 0.2 <= lower 0.8"),
    ("taylor_green", ["initial.fill_lower=[1.0, 0.0]"], "initial.fill_lower", "empty along axis 0"),
    # a fill past a periodic axis' end was dropped, not wrapped round (a fill of [-0.5, 0.5] kept half its fluid)
    ("taylor_green", ["initial.fill_lower=[-0.5, 0.0]", "initial.fill_upper=[0.5, 1.0]"], "initial.fill_lower",
     "-0.5 along axis 0 lies beyond the domain (0) on a periodic axis"),
    ("taylor_green", ["initial.fill_upper=[1.0, 1.5]"], "initial.fill_upper", "1.5 along axis 1 lies beyond"),
    # (a style audit: the kinematic run was told "not 'iips'", its method; psph info passed the checkpoints)
    ("kinematic_tgv", ["iips.update=mls2"], "iips.update", "this scene has physics.scheme = 'kinematic', not a "
     "fluid scheme"),
    ("static_perturbed", ["output.checkpoint_every=5"], "output.checkpoint_every", "not static ones"),
    # a rotated container's plates would not meet themselves across the periodic axis
    ("couette", ["bodies.0.angle=5.0"], "bodies[0].angle", "only unrotated"),
    ("couette", ["domain.periodic=[true, true]", "bodies.0.lid_velocity=[]"], "bodies[0].shape", "keep no wall"),
    # a free-slip wall takes no shear from its lid: the plates' fluid stayed at rest, exit 0
    ("couette", ["bodies.0.wall=free_slip"], "bodies[0].lid_velocity", "its lid would move no fluid"),
    ("couette", ["bodies.0.wall=free_slip", "bodies.0.model=ghost"], "bodies[0].lid_velocity", "a free-slip wall"),
    # a hydrostatic surface above where the fluid is cut (it ran with the pressure of a column 0.3 higher)
    ("hydrostatic_tank", ["initial.fill_upper=[2.0, 1.5]"], "initial.fill_upper",
     "free surface 1.5 is above the domain's top, 1.2, where the fluid is cut"),
    ("hydrostatic_tank", ["bodies.0.size=[2.0, 1.0]", "bodies.0.center=[1.0, 0.5]", "initial.fill_upper=[2.0, 1.1]"],
     "initial.fill_upper", "above the fluid's top lattice row, y = 0.9875, 4 row(s) below the fill region's"),
    ("hydrostatic_tank", ["bodies.0.size=[2.0, 1.0]", "bodies.0.center=[1.0, 0.5]", "initial.fill_upper=[2.0, 1.02]"],
     "initial.fill_upper", "y = 0.9875, 1 row(s) below the fill region's: a wall or body cuts the fluid there; "
     "give at most 1"),
    # any container: a rotated box (top corner 1.065), a polygon whose top is 0.9 (the scenes' fill 1.0 and 1.1)
    ("hydrostatic_tank", ["bodies.0.size=[1.4, 0.8]", "bodies.0.center=[1.0, 0.55]", "bodies.0.angle=10.0",
                          "initial.fill_upper=[2.0, 1.1]"], "initial.fill_upper", "a wall or body cuts the fluid"),
    ("trapezoidal_tank", ["bodies.0.vertices=[[0.0, 0.0], [1.0, 0.0], [1.6, 0.9], [0.0, 0.9]]"], "initial.fill_upper",
     "free surface 1 is above the fluid's top lattice row, y = 0.9, 2 row(s) below"),
])
def test_dam_break_keys_are_refused_where_they_do_not_apply(scene, sets, key, words):
    with pytest.raises(SceneError) as info:
        load_scene(CASES / f"{scene}.toml", sets)
    assert info.value.key == key and words in str(info.value), str(info.value)


def test_a_fill_region_between_lattice_nodes_is_refused():
    """A fill region that is not empty but holds no node of the lattice: no fluid particle (the run went on
    with none, and a NaN volume error). A jet's fluid, which its inflow buffer brings, may start empty."""
    from mpi4py import MPI

    from psph.initial import create_particles

    scene = load_scene(CASES / "taylor_green.toml", ["domain.dx=0.1", "initial.fill_lower=[0.31, 0.31]",
                                                      "initial.fill_upper=[0.32, 0.32]"])
    with pytest.raises(SceneError, match="no lattice node of dx = 0.1") as info:
        create_particles(scene, MPI.COMM_SELF)
    assert info.value.key == "initial.fill_upper"
    jet = load_scene(CASES / "impinging_jet.toml", ["domain.dx=0.1"])
    assert create_particles(jet, MPI.COMM_SELF).n_owned > 0


def test_artificial_viscosity_sets_nu_from_h_and_c0():
    """nu = alpha h c0 / (2 (d + 2)): Monaghan's artificial viscosity alpha h c0 rho0 sum_j pi_ij grad W V_j
    with pi_ij = (u_j - u_i) . x_ji / r^2 is the pi_ij operator of seed 001 eq. 11 (K = 2 (d + 2)) with
    mu K = alpha h c0 rho0; without alpha, nu = U L / Re."""
    scene = load_scene(CASES / "dam_break.toml")
    d, ph = scene.domain, scene.physics
    assert math.isclose(ph.kinematic_viscosity(d), 0.01 * (2 * d.dx) * 20.0 / 8.0, rel_tol=1e-14)
    plain = load_scene(CASES / "dam_break.toml", ["physics.artificial_viscosity=0", "physics.reynolds=250"])
    assert math.isclose(plain.physics.kinematic_viscosity(plain.domain), 1.0 / 250.0, rel_tol=1e-14)


def test_a_container_shorter_than_a_periodic_axis_is_refused():
    """A box container spans its periodic axes (the Couette plates): shorter, its sides there would be
    walls the periodic fluid crosses."""
    load_scene(CASES / "couette.toml", ["bodies.0.size=[0.5, 1.0]", "bodies.0.center=[0.3, 0.5]"])
    with pytest.raises(SceneError) as info:
        load_scene(CASES / "couette.toml", ["bodies.0.size=[0.4, 1.0]"])
    assert info.value.key == "bodies[0].size" and "periodic axis 0" in str(info.value)


@pytest.mark.parametrize("sets, bare", [
    (["domain.periodic=[false, false]"], "x-, x+, y-, y+"),
    (["domain.periodic=[true, false]", "initial.fill_upper=[1.0, 0.8]"], "y-"),
    (["domain.periodic=[false, false]", 'bodies=[{name="c", shape="ellipse", center=[0.5, 0.5], size=[0.1, 0.1]}]'],
     "x-, x+, y-, y+"),  # an immersed body walls no face
])
def test_static_shifting_at_a_bare_bounded_face_is_refused_by_face(sets, bare):
    """A drivers audit: IIPS pushed the particles of a bounded face with no wall out of the domain (exit 3 at
    iteration 1); a container, a periodic axis or a free surface (the fill region short of the face) is needed."""
    with pytest.raises(SceneError) as info:
        load_scene(CASES / "static_perturbed.toml", ["shifting.method=iips", *sets])
    assert info.value.key == "domain.periodic" and f"the bounded face(s) {bare} have no neighbour" in str(info.value)
    walled = ["domain.periodic=[false, false]",
              'bodies=[{name="box", shape="box", center=[0.5, 0.5], size=[1.0, 1.0]}]']
    assert load_scene(CASES / "static_perturbed.toml", ["shifting.method=iips", *walled]).bodies


def test_the_fictitious_pressure_is_refused_where_the_volumes_stay_constant():
    """P^F = p_ref V0 / V (thesis eq. 7.3) is p_ref throughout when V stays V0: the run was Neuhauser with
    P_S = 1 under another name (an audit: the shift velocities of both were equal to 0.0)."""
    sets = ["shifting.method=neuhauser", "iips.update=none", "shifting.fictitious_pressure=true"]
    with pytest.raises(SceneError) as info:
        load_scene(CASES / "taylor_green.toml", [*sets, "physics.scheme=delta_ale_const_volume"])
    assert info.value.key == "shifting.fictitious_pressure" and "neuhauser_ps = 1" in str(info.value)
    assert load_scene(CASES / "taylor_green.toml", [*sets, "physics.scheme=delta_ale_const_mass"])
    with pytest.raises(SceneError) as info:  # a kinematic run's volumes stay dx^d
        load_scene(CASES / "kinematic_tgv.toml", sets)
    assert info.value.key == "shifting.fictitious_pressure" and "'kinematic'" in str(info.value)
    assert load_scene(CASES / "kinematic_tgv.toml", sets[:2]).shifting.method == "neuhauser"
    with pytest.raises(SceneError, match="inside a fluid scheme or a kinematic run; physics.scheme is 'none'"):
        load_scene(CASES / "static_perturbed.toml", ["shifting.method=delta_plus"])


def test_a_scene_saved_with_a_byte_order_mark_loads(tmp_path):
    """Some editors begin UTF-8 files with a byte-order mark: TOML refused it at line 1, column 1."""
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + (CASES / "taylor_green.toml").read_bytes())
    assert load_scene(path).name == "taylor_green"


def test_free_surface_keys_are_named_unread_exactly_where_no_detection_runs():
    """A free-surface audit: free_surface.* set in a run that detects no surface went unnamed. Scene.
    detects_free_surface, which names them, agrees with what the scheme and the shifting method build, over
    the scenes and the settings that decide it (the combinations a scene refuses, riemann_ale with walls
    for one, left out). A scene with no shifting but the IIPS pre-procedure detects it too."""
    from psph.boundaries.free_surface import make_free_surface
    from psph.schemes import make_scheme

    seen = {True: 0, False: 0}
    for case in ("elliptical_drop", "dam_break", "hydrostatic_tank", "impinging_jet", "taylor_green",
                 "lid_driven_cavity", "static_perturbed"):
        for sets in ([], ["shifting.method=none"], ["shifting.method=delta_plus"],
                     ["shifting.method=none", "physics.tensile_switch=true"],
                     ["shifting.method=none", "physics.wall_adhesion=true"],
                     ["shifting.method=none", "free_surface.lambda_diffusion=0.2"],
                     ["shifting.method=none", "physics.scheme=riemann_ale"],
                     ["shifting.method=none", "iips.pre_newton=2"]):
            try:
                scene = load_scene(CASES / f"{case}.toml", [*sets, "free_surface.lambda_surface=0.3",
                                                            "iips.update=none"])
            except SceneError:
                continue
            if scene.physics.scheme == "none":
                detects = make_free_surface(scene).active
            else:
                scheme = make_scheme(scene)
                detects = scheme.surface.active or getattr(scheme, "step_surface", None) is not None
                if scene.iips.pre_newton > 0:  # the fluid driver's pre-procedure restricts its shifting there
                    detects = detects or make_free_surface(scene, pre_procedure=True).active
            assert scene.detects_free_surface() == detects, (case, sets)
            assert ("free_surface.lambda_surface" in scene.unread_keys()) == (not detects), (case, sets)
            seen[detects] += 1
    assert seen[True] >= 10 and seen[False] >= 10, seen


@pytest.mark.parametrize("case, sets, key", [
    # a keys audit: each was read nowhere in such a run, and psph info / run did not name it
    ("taylor_green_thesis", ["physics.tensile_switch=false"], "physics.tensile_switch"),
    ("kinematic_tgv", ["diagnostics.stop_at_cartesian=1.5"], "diagnostics.stop_at_cartesian"),
    ("taylor_green", ["diagnostics.stop_at_cartesian=1.5"], "diagnostics.stop_at_cartesian"),
    ("hydrostatic_tank", ["shifting.method=iips", "free_surface.lambda_normal=0.6"], "free_surface.lambda_normal"),
    ("taylor_green", ["shifting.method=neuhauser", "iips.update=none", "shifting.fictitious_pressure=true",
                      "shifting.neuhauser_ps=1"], "shifting.neuhauser_ps"),
    ("dam_break", ["physics.reynolds=500"], "physics.reynolds"),
    ("taylor_green", ["physics.scheme=delta_ale_const_mass", "physics.max_volume_variation=0.3"],
     "physics.max_volume_variation"),
    ("kinematic_tgv", ["shifting.method=explicit_iterative", "iips.beta=0", "iips.on_stall=stop"], "iips.on_stall"),
    ("static_perturbed", ["shifting.method=explicit_iterative", "shifting.iterations_per_step=5"],
     "shifting.iterations_per_step"),
    ("kinematic_tgv", ["shifting.method=explicit_iterative", "iips.beta=0", "shifting.max_iterations=5"],
     "shifting.max_iterations"),
    # (a new user's audit: positions bit-identical with and without them, and no word)
    ("static_perturbed", ["physics.gravity=[0.0, -9.81]"], "physics.gravity"),
    ("static_perturbed", ["physics.density=1000"], "physics.density"),
    ("static_perturbed", ["physics.sound_speed=20"], "physics.sound_speed"),
    ("static_perturbed", ["physics.reference_velocity=2"], "physics.reference_velocity"),
    ("kinematic_tgv", ["physics.gravity=[0.0, -9.81]"], "physics.gravity"),
    ("kinematic_tgv", ["physics.density=1000"], "physics.density"),
])
def test_a_key_a_run_does_not_read_is_named(case, sets, key):
    scene = load_scene(CASES / f"{case}.toml", sets)
    assert key in scene.unread_keys(), scene.unread_keys()


@pytest.mark.parametrize("case, sets", [
    ("taylor_green", ["physics.tensile_switch=false"]),
    ("static_perturbed", ["diagnostics.stop_at_cartesian=1.5"]),
    ("hydrostatic_tank", ["shifting.method=delta_plus", "free_surface.lambda_normal=0.6"]),
    ("taylor_green", ["shifting.method=neuhauser", "iips.update=none", "shifting.neuhauser_ps=1"]),
    ("taylor_green", ["physics.reynolds=500"]),
    ("taylor_green", ["physics.max_volume_variation=0.3"]),
    ("kinematic_tgv", ["iips.on_stall=stop"]),
    ("static_perturbed", ["shifting.method=explicit_iterative", "shifting.max_iterations=5"]),
    ("kinematic_tgv", ["shifting.method=explicit_iterative", "iips.beta=0", "shifting.iterations_per_step=5"]),
    ("kinematic_tgv", ["physics.sound_speed=20"]),  # its time step
    ("kinematic_tgv", ["physics.reference_velocity=2"]),  # its frozen field
    ("static_perturbed", ["initial.velocity=taylor_green", "physics.density=1000"]),  # the fields written
    ("static_perturbed", ["initial.velocity=taylor_green", "physics.reference_velocity=2"]),
    ("static_perturbed", ["initial.pressure=hydrostatic", "physics.gravity=[0.0, -9.81]"]),
    ("kinematic_tgv", ["initial.velocity=zero", "initial.pressure=hydrostatic", "physics.gravity=[0.0, -1.0]",
                       "physics.density=1000"]),
])
def test_a_key_a_run_reads_is_not_named_unread(case, sets):
    key = sets[-1].split("=")[0]
    assert key not in load_scene(CASES / f"{case}.toml", sets).unread_keys()
