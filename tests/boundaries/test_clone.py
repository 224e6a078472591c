"""Clone particles (seed 004 section III): the local mirroring of normals (eq. 5, sign corrected), of the
divergence velocity (eq. 6), of the Laplacian velocity (eq. 7) and of the pressure (eq. 8-9, with the full
body-force term), checked on the particles of a real scene next to a wall and at a corner."""

from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from psph.drivers.fluid import FluidDriver
from psph.particles import Kind
from psph.scene.load import load_scene
from tests.helpers import CASES

DX = 0.05


def cavity(tmp_path, **sets):
    scene = load_scene(CASES / "lid_driven_cavity.toml", [f"domain.dx={DX}", *[f"{k}={v}" for k, v in sets.items()]])
    driver = FluidDriver(scene, MPI.COMM_SELF, tmp_path)
    system = driver.system
    p = system.particles
    for name in ("velocity", "pressure"):
        p[name][:] = 0.0
    p["density"][:] = scene.physics.density
    driver.scheme.walls.place(system, 0.0)
    p["velocity"][p["kind"] != Kind.FLUID] = 0.0
    return driver, system, p


def wall_rates(driver, system, row, velocity=(0.0, 0.0), pressure=0.0):
    """(d rho, d momentum) the walls alone give fluid particle `row` moving at `velocity`."""
    p = system.particles
    p["velocity"][row] = velocity
    p["pressure"][row] = pressure
    d_rho, d_mom = np.zeros(p.n_local), np.zeros((p.n_local, 2))
    walls = driver.scheme.walls
    lid = walls.bodies[0].lid.copy()
    walls.add(system, driver.scheme, 0.0, d_rho, d_mom)
    assert np.array_equal(lid, walls.bodies[0].lid)
    return d_rho[row], d_mom[row]


def particle_at(p, x, y):
    pos = p.owned("position")
    fluid = p.owned("kind") == Kind.FLUID
    d = np.where(fluid, np.hypot(pos[:, 0] - x, pos[:, 1] - y), np.inf)
    return int(np.argmin(d))


def test_approach_to_a_wall_compresses_and_pressure_repels(tmp_path):
    """Moving towards the bottom wall mirrors the normal velocity (eq. 6): the particle is compressed;
    moving along it is not; a positive pressure is pushed back by the clones (eq. 8)."""
    driver, system, p = cavity(tmp_path, **{"physics.reynolds": 1e12})
    i = particle_at(p, 0.5 + DX / 2, DX / 2)
    towards, _ = wall_rates(driver, system, i, velocity=(0.0, -1.0))
    along, _ = wall_rates(driver, system, i, velocity=(1.0, 0.0))
    assert towards > 0 and abs(along) < 1e-12 * towards
    _, push = wall_rates(driver, system, i, pressure=1.0)
    assert push[1] > 0 and abs(push[0]) < 1e-10 * push[1]


def test_sliding_along_a_wall_off_the_lattice_neither_compresses_nor_expands(tmp_path):
    """Eq. 6 keeps the tangential velocity, u_j . t = u_i . t: a particle sliding along the bottom wall has
    u_j = u_i at every clone, whatever the clones' arrangement around it. Off the lattice's symmetry (moved
    0.15 dx along the wall) a reversed tangential part would compress it; on the lattice the sums cancel
    by symmetry, which let a wall audit's sign mutant pass this file."""
    driver, system, p = cavity(tmp_path, **{"physics.reynolds": 1e12})
    i = particle_at(p, 0.5 + DX / 2, DX / 2)
    towards, _ = wall_rates(driver, system, i, velocity=(0.0, -1.0))
    p["position"][i, 0] += 0.15 * DX
    along, _ = wall_rates(driver, system, i, velocity=(1.0, 0.0))
    assert abs(along) < 1e-12 * towards


def test_corner_second_wall_still_mirrors_the_approach(tmp_path):
    """Eq. 5 as printed (n_j . (r_j - r_i) > 0) holds for every ordinary wall particle, so every clone
    would take the closest node's normal: near a corner, approaching the other wall would not compress.
    With the corrected sign, a particle half a spacing from the left wall and 2.5 from the bottom is
    compressed when it moves down, about as much as at the same distance from a plain bottom wall."""
    driver, system, p = cavity(tmp_path, **{"physics.reynolds": 1e12})
    corner = particle_at(p, DX / 2, 2.5 * DX)
    plain = particle_at(p, 0.5 + DX / 2, 2.5 * DX)
    down_corner, _ = wall_rates(driver, system, corner, velocity=(0.0, -1.0))
    down_plain, _ = wall_rates(driver, system, plain, velocity=(0.0, -1.0))
    assert down_plain > 0 and down_corner > 0.5 * down_plain


@pytest.mark.parametrize("side,velocity", [("bottom", 0.0), ("lid", 1.0)])
@pytest.mark.parametrize("along", [0.0, 0.125])
def test_laplacian_mirror_is_the_linear_extension_of_a_shear(tmp_path, side, velocity, along):
    """Eq. 7: for u = u_b + gamma s (s: distance from the wall), the clones carry u_b - gamma s_j, the
    linear continuation, so the wall's viscous force equals the one of a fluid continued beyond the wall
    with that profile: for each fluid particle near the wall, fluid + clone viscous sums equal the sum over
    the full lattice of the continued profile. `along`: the particle moved that many dx along the wall,
    0.125 dx putting it halfway between two body nodes (ds = dx/4 apart), where its distance to the closest
    node exceeds its distance to the wall by 3.1% and the clones' velocities fell short of the line by as
    much (a walls audit: seed 004's s_i is the distance to the contour)."""
    driver, system, p = cavity(tmp_path, **{"physics.reynolds": 1.0})
    pos = p["position"]
    pos[particle_at(p, 0.5 + DX / 2, DX / 2 if side == "bottom" else 1.0 - DX / 2), 0] += along * DX
    gamma = 0.7
    dist = pos[:, 1] if side == "bottom" else 1.0 - pos[:, 1]
    profile = velocity - gamma * dist if side == "lid" else gamma * dist
    fluid = p["kind"] == Kind.FLUID
    p["velocity"][:, 0] = np.where(fluid, profile, p["velocity"][:, 0])
    from psph.compute.sums import viscous_pi

    i = particle_at(p, 0.5 + DX / 2, DX / 2 if side == "bottom" else 1.0 - DX / 2)
    d_rho, d_mom = np.zeros(p.n_local), np.zeros((p.n_local, 2))
    driver.scheme.walls.add(system, driver.scheme, 0.0, d_rho, d_mom)
    mu = driver.scheme.mu
    fluid_only = np.zeros((p.n_local, 2))
    u_fluid = np.where(fluid[:, None], p["velocity"], 0.0)
    vol_fluid = np.where(fluid, p["volume"], 0.0)
    viscous_pi(pos, vol_fluid, system.nbr_ptr, system.nbr_idx, system.kernel.params, u_fluid, fluid_only)
    continued = np.zeros((p.n_local, 2))
    u_all = np.stack([profile, np.zeros(p.n_local)], 1)
    viscous_pi(pos, p["volume"], system.nbr_ptr, system.nbr_idx, system.kernel.params, u_all, continued)
    wall_part = d_mom[i] / p["volume"][i] / mu
    assert np.allclose(fluid_only[i] + wall_part, continued[i], atol=1e-9 * gamma / DX)


@pytest.mark.parametrize("where", ["wall", "corner"])
def test_negative_pressure_is_not_pulled_into_the_wall(tmp_path, where):
    """Tensile switch (seed 004 eq. 3): where p_i < 0 the pressure force is -sum_j (p_j - p_i) grad_i W_ij V_j
    over every neighbour, the clones included. Applied to the fluid pairs only, a particle in uniform
    suction (p_j = p_i < 0 on both sides) kept 2 |p_i| |sum_clones grad_i W_ij V_j| of attraction to the
    wall: the moving square's wake particles were pulled through its rear corner (t = 0.94 at D/dx = 10).
    With the switch on the clones too, uniform suction exerts no force on the particle; without the switch
    the plus form pulls it to the wall; the force on the body stays the plus form's (suction drags it)."""
    driver, system, p = cavity(tmp_path, **{"physics.reynolds": 1e12})
    i = particle_at(p, 0.5 + DX / 2 if where == "wall" else DX / 2, DX / 2)
    _, push = wall_rates(driver, system, i, pressure=1.0)
    body_push = driver.scheme.walls.force[0, 0].copy()
    _, pull = wall_rates(driver, system, i, pressure=-1.0)
    body_pull = driver.scheme.walls.force[0, 0].copy()
    assert push[1] > 0 and np.abs(pull).max() < 1e-12 * push[1]
    assert body_push[1] < 0 and np.allclose(body_pull, -body_push, rtol=1e-12)
    driver.scheme.tensile = False
    _, plus = wall_rates(driver, system, i, pressure=-1.0)
    assert np.allclose(plus, -push, rtol=1e-12)


def rectangle_coefficients(tmp_path, dx, angle, pressure, velocity):
    """Force and moment coefficients (WallTerms.body_forces) of a rectangle 1 x 0.5 centred in a periodic
    3 x 3 box (the ellipse scene's physics), for prescribed fluid fields pressure(x', y') and velocity(r)
    (body coordinates x', r about the centre) at t = 0."""
    scene = load_scene(CASES / "inclined_ellipse.toml", [
        f"domain.dx={dx}", "domain.upper=[3.0, 3.0]", "bodies.0.shape=rectangle", "bodies.0.center=[1.5, 1.5]",
        "bodies.0.size=[1.0, 0.5]", f"bodies.0.angle={angle}"])
    driver = FluidDriver(scene, MPI.COMM_SELF, tmp_path)
    system, walls = driver.system, driver.scheme.walls
    p = system.particles
    walls.place(system, 0.0)
    rot = np.deg2rad(angle)
    r = p["position"] - 1.5
    local = r @ np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]])
    fluid = p["kind"] == Kind.FLUID
    p["pressure"][:] = pressure(local[:, 0], local[:, 1])
    p["density"][:] = scene.physics.density
    p["velocity"][:] = 0.0
    p["velocity"][fluid] = velocity(r[fluid])
    d_rho, d_mom = np.zeros(p.n_local), np.zeros((p.n_local, 2))
    walls.add(system, driver.scheme, 0.0, d_rho, d_mom)
    return walls.body_forces(MPI.COMM_SELF)


@pytest.mark.parametrize("angle", [0.0, 30.0])
def test_torque_of_a_quadratic_pressure_field_converges(tmp_path, angle):
    """A rectangle a x b in p = G x' y' (body coordinates about its centre) feels no force and the torque
    T = -integral(x' dp/dy' - y' dp/dx') dV = -G a b (a^2 - b^2) / 12 (divergence theorem): the history's
    cm_pressure = 2 T / (rho0 U^2 a^2). The clones carry the particle's own pressure to the wall (seed 004
    eq. 8), so the wall sees p a distance s_i out: the error is first order (20%, 10%, 5% at dx = 0.05,
    0.025, 0.0125)."""
    a, b, g = 1.0, 0.5, 2.0
    expected = 2.0 * (-g * a * b * (a * a - b * b) / 12.0) / a ** 2
    errors = []
    for dx in (0.025, 0.0125):
        coeff = rectangle_coefficients(tmp_path, dx, angle, lambda x, y: g * x * y, lambda r: 0.0 * r)
        errors.append(abs(coeff["cm_pressure"] / expected - 1.0))
        assert abs(coeff["cd_pressure"]) < 1e-3 * abs(expected) and abs(coeff["cl_pressure"]) < 1e-3 * abs(expected)
    assert errors[1] < 0.07 and 1.6 < errors[0] / errors[1] < 2.5


def test_viscous_torque_turns_the_body_with_the_fluid(tmp_path):
    """A fluid turning anticlockwise round a body at rest drags it along: cm_viscous > 0, and < 0 the other
    way round."""
    turn = {sign: rectangle_coefficients(tmp_path, 0.025, 30.0, lambda x, y: 0.0 * x,
                                         lambda r, s=sign: s * 0.1 * np.stack([-r[:, 1], r[:, 0]], axis=1))
            for sign in (1.0, -1.0)}
    assert turn[1.0]["cm_viscous"] > 0.0 and turn[-1.0]["cm_viscous"] == pytest.approx(-turn[1.0]["cm_viscous"])


def test_free_slip_walls_exert_no_shear(tmp_path):
    """Free slip (seed 004: the Laplacian velocity of the clones is the particle's own): a particle
    sliding along the bottom wall feels no wall friction and the box no viscous force; with no-slip it is
    braked (eq. 7). (A free-slip box has no lid: the scene refuses one.)"""
    rates = {}
    for wall in ("free_slip", "no_slip"):
        driver, system, p = cavity(tmp_path, **{"physics.reynolds": 1.0, "bodies.0.wall": wall,
                                                "bodies.0.lid_velocity": "[]" if wall == "free_slip" else "[1.0, 0.0]"})
        i = particle_at(p, 0.5 + DX / 2, DX / 2)
        _, rates[wall] = wall_rates(driver, system, i, velocity=(1.0, 0.0))
        rates[wall + " body"] = driver.scheme.walls.force[0, 1].copy()
    assert rates["no_slip"][0] < 0.0 and np.abs(rates["no_slip body"]).max() > 0.0
    assert np.abs(rates["free_slip"]).max() < 1e-12 * abs(rates["no_slip"][0])
    assert np.abs(rates["free_slip body"]).max() == 0.0


def test_shifting_towards_a_wall_compresses_and_along_it_does_not(tmp_path):
    """The walls' du terms of the continuity equation: a particle shifted towards the bottom wall is
    compressed, one shifted along it is not. (With rho_j = rho_i these terms reduce to the particle's own
    du, so this does not tell the clones' mirrored du from an unmirrored one; the next test does.)"""
    driver, system, p = cavity(tmp_path, **{"physics.reynolds": 1e12, "shifting.method": "delta_plus",
                                            "iips.update": "none"})
    assert driver.scheme.shift.active
    i = particle_at(p, 0.5 + DX / 2, DX / 2)
    d_rho = {}
    for name, du in (("towards", (0.0, -1.0)), ("along", (1.0, 0.0))):
        p["shift_velocity"][:] = 0.0
        p["shift_velocity"][i] = du
        d_rho[name], _ = wall_rates(driver, system, i)
    assert abs(d_rho["towards"]) > 0.0 and abs(d_rho["along"]) < 1e-12 * abs(d_rho["towards"])


def test_the_clones_shifting_velocity_is_mirrored(tmp_path):
    """The momentum's du term sees the clones' own du_j, mirrored (du . n reversed): a particle sliding along
    a free-slip wall (u tangential; the clones' divergence velocity is then u_i) and shifted into it gets
    u_i rho (du_j + du_i) . grad W V_j = 0 from every clone, where an unmirrored du_j = du_i would give
    2 u_i rho du_i . grad W V_j. With no pressure and no shear (free slip), the walls' whole x-momentum
    rate is that term; the walls' density rate of the same particle, 2 rho du_i . sum_j grad W V_j, times
    dx gives its size (unmirrored, the x-rate is 5% of that)."""
    driver, system, p = cavity(tmp_path, **{"physics.reynolds": 1e12, "shifting.method": "delta_plus",
                                            "iips.update": "none", "bodies.0.wall": "free_slip",
                                            "bodies.0.lid_velocity": "[]"})
    assert driver.scheme.variant == 0
    i = particle_at(p, 0.5 + DX / 2, DX / 2)
    p["shift_velocity"][:] = 0.0
    p["shift_velocity"][i] = (0.0, -1.0)
    d_rho, sliding = wall_rates(driver, system, i, velocity=(1.0, 0.0))
    size = abs(d_rho) * DX  # rho du . sum grad W V_j times a length: a momentum rate of the term's size
    assert size > 0.0
    assert abs(sliding[0]) < 1e-12 * size


def test_several_bodies_get_suffixed_columns_and_their_own_forces(tmp_path):
    """Two blocks held in the hydrostatic tank: each body's columns carry its name, and each feels its own
    displaced weight, cl_pressure = 2 A / D (g = rho0 = U = 1): 0.6 and 0.4 (first right-hand side)."""
    from psph.scene.load import apply_overrides, read_table, scene_from_table

    table = apply_overrides(read_table(Path(__file__).parent / "buoyancy.toml"),
                            ["bodies.1.center=[0.6, 0.5]", "bodies.1.name=first"])
    table["bodies"].append(dict(table["bodies"][1], name="second", center=[1.4, 0.5], size=[0.4, 0.2]))
    scene = scene_from_table(table)
    driver = FluidDriver(scene, MPI.COMM_SELF, tmp_path)
    system, walls = driver.system, driver.scheme.walls
    p = system.particles
    walls.place(system, 0.0)
    p["velocity"][:] = 0.0
    walls.add(system, driver.scheme, 0.0, np.zeros(p.n_local), np.zeros((p.n_local, 2)))
    coeff = walls.body_forces(MPI.COMM_SELF)
    tank = scene.bodies[0].name
    assert sorted(coeff) == sorted([f"{c}_{part}_{name}" for c in ("cd", "cl", "cm") for part in ("pressure", "viscous")
                                    for name in ("first", "second")] + [f"force_x_{tank}", f"force_y_{tank}"])
    assert coeff["cl_pressure_first"] == pytest.approx(0.6, rel=0.05)
    assert coeff["cl_pressure_second"] == pytest.approx(0.4, rel=0.05)
    assert abs(coeff["cd_pressure_first"]) < 0.01 and abs(coeff["cd_pressure_second"]) < 0.01


def test_at_a_convex_corner_the_clones_take_the_particles_own_normal(tmp_path):
    """Eq. 5 (sign corrected) at a body's convex corner: a fluid particle just above the top face of a
    free-slip rectangle, a few spacings from its corner, lies behind solid particles of the side face (their
    normals, -x, see it on their solid side), so all its clones use its own normal (-y). Sliding along the
    top face, it then sees its own velocity in every clone (free slip mirrors only u . n = 0) and no
    density rate from the wall, while approaching the face it does. With each solid particle's own normal,
    the side face's clones would mirror u_x and compress it."""
    scene = load_scene(CASES / "inclined_ellipse.toml", [
        f"domain.dx={DX}", "domain.upper=[3.0, 3.0]", "bodies.0.shape=rectangle", "bodies.0.center=[1.5, 1.5]",
        "bodies.0.size=[1.0, 0.5]", "bodies.0.angle=0", "bodies.0.wall=free_slip", "shifting.method=none"])
    driver = FluidDriver(scene, MPI.COMM_SELF, tmp_path)
    system = driver.system
    p = system.particles
    p["velocity"][:] = 0.0
    p["pressure"][:] = 0.0
    p["density"][:] = scene.physics.density
    driver.scheme.walls.place(system, 0.0)
    i = particle_at(p, 2.0 - 3.5 * DX, 1.75 + DX / 2)
    assert p["position"][i, 1] > 1.75 and p["position"][i, 0] < 2.0 - 3 * DX
    # the branch is taken: some solid neighbour within the support sees the particle behind its wall
    nbrs = system.nbr_idx[system.nbr_ptr[i]:system.nbr_ptr[i + 1]]
    solid = nbrs[p["kind"][nbrs] != Kind.FLUID]
    r = p["position"][i] - p["position"][solid]
    behind = (np.einsum("ij,ij->i", p["normal"][solid], r) > 0) & (np.hypot(*r.T) < system.kernel.support)
    assert behind.any() and np.allclose(p["normal"][solid[behind]], [-1.0, 0.0])
    d_rho_approach, _ = wall_rates(driver, system, i, velocity=(0.0, -1.0))
    d_rho_slide, _ = wall_rates(driver, system, i, velocity=(1.0, 0.0))
    assert d_rho_approach > 0.0
    assert abs(d_rho_slide) < 1e-12 * d_rho_approach


def test_a_wall_s_clones_are_mirrored_by_the_distance_to_that_wall_not_to_a_nearer_body(tmp_path):
    """A particle sliding in the 2 dx gap between the floor and a block above it, 0.025 below the block
    and 0.075 above the floor: the floor's clones mirror its velocity with the distance to the floor, as
    without the block (its clones left out: their kind made fluid). With the closest node of any body, the
    block's, 3 times nearer, scaled the floor's mirrored velocities: its shear on the particle came out 1.5
    times too large (-0.076 against -0.050)."""
    block = "bodies=[{name='walls',shape='box',center=[0.5,0.5],size=[1.0,1.0],wall='no_slip'," \
            "lid_velocity=[1.0,0.0]},{name='block',shape='rectangle',center=[0.5,0.2],size=[0.4,0.2]}]"
    rates = {}
    for name, sets in (("floor", {}), ("floor and block", {"bodies": block[len("bodies="):]})):
        driver, system, p = cavity(tmp_path / name.replace(" ", "_"), **{"physics.reynolds": 1.0, **sets})
        assert np.any(p["body"] == 1) == (name != "floor")
        p["kind"][p["body"] == 1] = Kind.FLUID  # the block's solids (none without it) out of the wall terms
        i = particle_at(p, 0.5 + DX / 2, 1.5 * DX)
        assert np.allclose(p["position"][i], [0.5 + DX / 2, 1.5 * DX])
        rates[name] = wall_rates(driver, system, i, velocity=(1.0, 0.0))[1]
    assert rates["floor"][0] < 0.0
    assert np.allclose(rates["floor and block"], rates["floor"], rtol=1e-12, atol=0.0), rates


def test_a_body_s_node_tree_is_kept_only_while_it_does_not_move():
    """The closest-node search keeps one k-d tree per clone body: a fixed wall's is built once, a moving
    body's at every time asked (with its nodes where they are then)."""
    from psph.boundaries.clone import WallTerms

    moving = WallTerms(load_scene(CASES / "moving_square.toml"))
    early, late = moving._node_trees(0.0), moving._node_trees(2.0)
    assert early[0] is late[0]  # the tank
    assert early[1] is not late[1] and np.allclose(late[1][0].data, moving.clones[1].nodes(2.0)[0])
    assert not np.allclose(early[1][0].data, late[1][0].data)
    fixed = WallTerms(load_scene(CASES / "hydrostatic_tank.toml"))
    assert fixed._node_trees(0.0)[0] is fixed._node_trees(5.0)[0]


def test_no_shifting_into_a_wall_in_the_free_surface_region(tmp_path):
    """WallTerms.keep_shift_off: a row of the free-surface region closer than dx/2 to a wall loses its
    shifting velocity's part into the wall (the floor, the right wall, the lid; into both walls in a
    corner), keeps the rest and the part out of the wall; a row farther than dx/2 or outside the region
    keeps its du, and so does every other row."""
    driver, system, p = cavity(tmp_path, **{"shifting.method": "delta_plus", "iips.update": "none"})
    near, top = 0.3 * DX, 1.0 - 0.3 * DX
    cases = {  # where, du given, du expected
        "floor": ((0.5 + DX / 2, near), (0.3, -1.0), (0.3, 0.0)),
        "right wall": ((top, 0.5 + DX / 2), (1.0, 0.3), (0.0, 0.3)),
        "lid": ((0.5 + DX / 2, top), (-0.2, 0.7), (-0.2, 0.0)),
        "corner": ((near, near), (-0.5, -1.0), (0.0, 0.0)),
        "off the floor": ((0.5 + DX / 2, near), (0.3, 1.0), (0.3, 1.0)),
        "beyond dx/2": ((0.5 + DX / 2, 0.6 * DX), (0.3, -1.0), (0.3, -1.0)),
        "outside the region": ((0.5 - DX / 2, near), (0.3, -1.0), (0.3, -1.0))}
    rng = np.random.default_rng(3)
    for name, ((x, y), given, expected) in cases.items():
        i = particle_at(p, x, y)
        p.owned("position")[i] = (x, y)
        region = np.zeros(p.n_owned, dtype=bool)
        region[i] = name != "outside the region"
        du = rng.normal(size=(p.n_owned, 2))
        du[i] = given
        before = du.copy()
        driver.scheme.walls.keep_shift_off(system, 0.0, region, du)
        assert np.allclose(du[i], expected, atol=1e-12), (name, du[i])
        others = np.arange(p.n_owned) != i
        assert np.array_equal(du[others], before[others])


@pytest.mark.parametrize("t", [0.0, 2.0])
def test_no_shifting_into_an_immersed_body(tmp_path, t):
    """The same for an immersed body (its node normals point out of the fluid too), where the moving square
    is at time t: a row 0.3 dx left of its left side, shifted towards its centre, keeps only the part along
    the side; 0.6 dx away it keeps all."""
    scene = load_scene(CASES / "moving_square.toml", ["domain.dx=0.05"])
    driver = FluidDriver(scene, MPI.COMM_SELF, tmp_path)
    system, walls = driver.system, driver.scheme.walls
    p = system.particles
    square = walls.clones[1]
    side = square.rigid(t)[0][0] - 0.5  # x of the left side (size 1)
    assert t == 0.0 or side > 1.5
    i = particle_at(p, 1.0, 2.5)
    for gap, expected in ((0.3, (0.0, 0.4)), (0.6, (1.0, 0.4))):
        p.owned("position")[i] = (side - gap * DX, 2.5 + DX / 2)
        du = np.zeros((p.n_owned, 2))
        du[i] = (1.0, 0.4)
        walls.keep_shift_off(system, t, np.ones(p.n_owned, dtype=bool), du)
        assert np.allclose(du[i], expected, atol=1e-12), (gap, du[i])


def test_off_walls_is_the_closest_admissible_vector():
    """compute.walls.off_walls against a constrained minimisation (SLSQP) of |v - du| subject to
    v . n <= 0 for every normal: a wall, a right-angled corner and an obtuse and an acute wedge."""
    from scipy.optimize import minimize

    from psph.compute.walls import off_walls

    rng = np.random.default_rng(5)
    for angle in (None, 90.0, 135.0, 45.0):
        normals = np.array([[0.0, -1.0]] + ([] if angle is None else
                                            [[-np.sin(np.radians(angle)), np.cos(np.radians(angle))]]))
        for du in rng.normal(size=(20, 2)):
            best = minimize(lambda v, du=du: ((v - du) ** 2).sum(), np.zeros(2), method="SLSQP",
                            constraints={"type": "ineq", "fun": lambda v, n=normals: -n @ v}, tol=1e-14).x
            got = du[None, :].copy()
            off_walls(np.vstack([normals, np.zeros((1, 2))])[None], np.zeros(1, dtype=np.int64), got)
            assert np.allclose(got[0], best, atol=1e-6), (angle, du)


def test_the_walls_caches_give_what_a_fresh_evaluation_does(tmp_path):
    """WallTerms keeps what a right-hand side would derive again at every stage: the near-wall rows
    (compute.walls.near_wall_rows, for the same lists and kinds) and the fixed bodies' wall velocities
    (written once for the particle arrays as they are). Neither may go stale: a kind flipped in place with
    the lists kept (an open boundary's outflow, boundaries.open), the rows reordered (a rebuild's sort), and a
    moving body's solids at another time, give what a fresh WallTerms computes."""
    from psph.boundaries.clone import WallTerms
    from psph.compute.walls import near_wall_rows

    scene = load_scene(CASES / "moving_square.toml", ["domain.dx=0.1"])
    driver = FluidDriver(scene, MPI.COMM_SELF, tmp_path)
    system, walls = driver.system, driver.scheme.walls
    p = system.particles

    def fresh_place(t):
        """The solids' fields at time t as a WallTerms without caches writes them."""
        kept = {name: p[name].copy() for name in ("wall_velocity", "velocity", "normal", "wall_accel")}
        WallTerms(scene)._place(system, t, positions=False)
        out = {name: p[name].copy() for name in kept}
        for name, value in kept.items():
            p[name][:] = value
        return out

    def assert_placed(t):
        expected = fresh_place(t)
        p.owned("wall_velocity")[p.owned("body") >= 0] = np.nan  # what a stale cache would leave there
        walls._place(system, t, positions=False)
        for name, value in expected.items():  # (the owned rows: the halo's are refreshed from them)
            assert np.array_equal(p.owned(name), value[: p.n_owned]), (t, name)

    tank = p["body"] == 0
    walls.place(system, 0.5)
    p["wall_velocity"][tank] = np.nan  # the tank's rows already written for these arrays: left alone
    walls.place(system, 0.7)
    assert np.isnan(p["wall_velocity"][tank]).all()
    system.rebuild()  # new particle arrays: the fixed bodies' rows are written again
    assert_placed(1.2)
    walls.link_nodes(system)  # the nodes taken again (a restart): likewise
    assert_placed(1.3)
    moving = p.owned("body") == 1
    assert not np.array_equal(fresh_place(0.6)["wall_velocity"][: p.n_owned][moving],
                              fresh_place(1.4)["wall_velocity"][: p.n_owned][moving])

    rows = walls._near_wall_rows(system)
    assert np.array_equal(rows, near_wall_rows(p["kind"], system.nbr_ptr, system.nbr_idx)) and len(rows)
    assert walls._near_wall_rows(system) is rows  # the same lists and kinds
    p["kind"][rows[:3]] = Kind.OUTLET  # in place, the lists kept
    changed = walls._near_wall_rows(system)
    assert np.array_equal(changed, near_wall_rows(p["kind"], system.nbr_ptr, system.nbr_idx))
    assert len(changed) == len(rows) - 3
    p["kind"][rows[:3]] = Kind.FLUID
    system.rebuild()
    again = walls._near_wall_rows(system)
    assert again is not rows and np.array_equal(again, near_wall_rows(p["kind"], system.nbr_ptr, system.nbr_idx))
