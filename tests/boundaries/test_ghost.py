"""Fixed ghost walls (the baseline of seed 001 section 6.2): the images the kernels enumerate and mirror on
the fly equal explicit mirror particles added to the fluid and summed by the fluid kernel (the flows with
ghost walls are in test_wall_flows.py)."""

import numpy as np
import pytest

from psph.compute import fluid, riemann
from psph.compute.neighbours import build_neighbour_lists
from psph.compute.shift_velocity import corrected_grad_c
from psph.compute.smoothing import make_kernel
from psph.compute.sums import renormalisation_and_grad_c
from psph.compute.walls import NO_MATRIX, RIEMANN_WALLS, RIEMANN_WALLS_LOW, ghost_grad_c, ghost_images, ghost_rhs

C0, RHO0, MU = 10.0, 1.0, 0.01
LID = np.array([0.7, 0.0])


def box_walls(lo=0.0, hi=1.0):
    """The four sides of [lo, hi]^2: axis, coordinate, inward sign, velocity (a lid on top)."""
    return {"axis": np.array([0, 0, 1, 1]), "coord": np.array([lo, hi, lo, hi]),
            "sign": np.array([1.0, -1.0, 1.0, -1.0]),
            "velocity": np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], LID])}


def fluid_in_box(rng, n_side=12):
    dx = 1.0 / n_side
    grid = (np.stack(np.meshgrid(np.arange(n_side), np.arange(n_side), indexing="ij"), -1).reshape(-1, 2) + 0.5) * dx
    pos = np.clip(grid + 0.15 * dx * rng.standard_normal(grid.shape), 0.02 * dx, 1.0 - 0.02 * dx)
    n = len(pos)
    rho = RHO0 * (1.0 + 0.01 * rng.standard_normal(n))
    return dict(pos=np.ascontiguousarray(pos), vol=dx * dx * (1.0 + 0.1 * rng.random(n)), rho=rho,
                prs=C0 * C0 * (rho - RHO0),  # the linear equation of state, as the images' densities assume
                vel=rng.standard_normal((n, 2)), du=0.1 * rng.standard_normal((n, 2))), dx


def explicit_images(f, walls, support, no_slip, gravity=(0.0, 0.0)):
    """Every fluid particle mirrored across each side it lies within a support of, and across both sides of
    a corner it is near, written out independently of the kernels: fields of the images, whose pressure is
    the hydrostatic extension p_j + rho_j g . (x_g - x_j) (seed 001 section 6.2), their density its
    linear equation of state's."""
    out = {k: [] for k in f}
    near = [walls["sign"][w] * (f["pos"][:, walls["axis"][w]] - walls["coord"][w]) < support for w in range(4)]
    sets = [(w,) for w in range(4)] + [(a, b) for a in (0, 1) for b in (2, 3)]
    for ws in sets:
        mask = np.logical_and.reduce([near[w] for w in ws])
        pos, vel, du = f["pos"][mask].copy(), f["vel"][mask].copy(), f["du"][mask].copy()
        for w in ws:
            a, ub = walls["axis"][w], walls["velocity"][w]
            pos[:, a] = 2.0 * walls["coord"][w] - pos[:, a]
            if no_slip:  # the Laplacian's mirror: the velocity reversed about the wall's
                vel = 2.0 * ub - vel
            else:  # the divergence's: the normal part reversed, the tangential kept
                vel[:, a] = 2.0 * ub[a] - vel[:, a]
            du[:, a] = -du[:, a]
        prs = f["prs"][mask] + f["rho"][mask] * ((pos - f["pos"][mask]) @ np.asarray(gravity))
        for k, v in (("pos", pos), ("vel", vel), ("du", du), ("vol", f["vol"][mask]), ("rho", RHO0 + prs / C0**2),
                     ("prs", prs)):
            out[k].append(v)
    return {k: np.concatenate([f[k]] + v) for k, v in out.items()}


def fluid_rates(f, n, kern, variant, with_shift, morris=False):
    """d_rho, d_mom of the first n rows from the fluid kernel over all rows (no diffusion, no gravity)."""
    ptr, idx = build_neighbour_lists(f["pos"], n, 1.1 * kern.support)
    kind = np.zeros(len(f["pos"]), dtype=np.int8)
    pairs, grad_rho = fluid.PairCache(), np.zeros((len(kind), 2))
    fluid.renormalised_gradient(f["pos"], f["vol"], f["rho"], ptr, idx, kern.params, kind, False, grad_rho, pairs)
    d_rho, d_mass, d_mom = np.zeros(n), np.zeros(n), np.zeros((n, 2))
    fluid.delta_ale_rhs(f["pos"], f["vol"], f["rho"], f["rho"] * f["vol"], f["vel"], f["du"], f["prs"], grad_rho,
                        pairs, kern.params, C0, 0.0, 0.0, MU, np.zeros(2), variant, with_shift, True, kind, False,
                        d_rho, d_mass, d_mom, morris=morris)
    return d_rho, d_mom


def ghost_rates(f, kern, variant, with_shift, no_slip, morris=False, gravity=(0.0, 0.0)):
    n = len(f["pos"])
    walls = box_walls()
    ptr, idx = build_neighbour_lists(f["pos"], n, 1.1 * kern.support)
    kind = np.zeros(n, dtype=np.int8)
    rows = np.arange(n)
    images = ghost_images(f["pos"], kind, rows, walls, ptr, idx, kern.support)
    d_rho, d_mom = fluid_rates(f, n, kern, variant, with_shift, morris)
    ghost_rhs(f["pos"], f["vol"], f["rho"], f["vel"], f["du"], f["prs"], rows, *images, walls["axis"],
              walls["coord"], walls["velocity"], no_slip, kern.params, C0, RHO0, False, MU, morris,
              np.array(gravity), variant, with_shift, np.ones(n, dtype=np.int8), d_rho, d_mom)
    return d_rho, d_mom, images


@pytest.mark.parametrize("variant", [0, 1])
def test_images_equal_explicit_mirror_particles(variant):
    """Free slip with shifting: the images' divergence velocity is also their Laplacian velocity, so the
    ghost terms plus the fluid's equal the fluid kernel over the fluid and its explicit mirror images
    (continuity with the du-terms, pressure, viscosity, the du-terms of the momentum)."""
    f, dx = fluid_in_box(np.random.default_rng(3 + variant))
    kern = make_kernel("wendland_c6", 2, 2.0 * dx)
    n = len(f["pos"])
    d_rho, d_mom, images = ghost_rates(f, kern, variant, True, False)
    assert images[0][-1] > 0 and (images[2][:, 1] >= 0).any()  # single and corner images
    want_rho, want_mom = fluid_rates(explicit_images(f, box_walls(), kern.support, False), n, kern, variant, True)
    assert np.abs(d_rho - want_rho).max() < 1e-10 * np.abs(want_rho).max()
    assert np.abs(d_mom - want_mom).max() < 1e-10 * np.abs(want_mom).max()


@pytest.mark.parametrize("variant", [0, 1])
def test_images_carry_the_hydrostatic_pressure_under_gravity(variant):
    """Under gravity the images' pressure is extended hydrostatically from their fluid particle's (and their
    density follows it): the ghost terms equal the fluid kernel's over explicit images so built, and differ
    from those without the extension (a wall audit: dropping it passed every fast test)."""
    f, dx = fluid_in_box(np.random.default_rng(5 + variant))
    kern = make_kernel("wendland_c6", 2, 2.0 * dx)
    n, gravity = len(f["pos"]), (0.3, -9.81)
    d_rho, d_mom, _ = ghost_rates(f, kern, variant, True, False, gravity=gravity)
    want_rho, want_mom = fluid_rates(explicit_images(f, box_walls(), kern.support, False, gravity), n, kern,
                                     variant, True)
    assert np.abs(d_rho - want_rho).max() < 1e-10 * np.abs(want_rho).max()
    assert np.abs(d_mom - want_mom).max() < 1e-10 * np.abs(want_mom).max()
    _, without = fluid_rates(explicit_images(f, box_walls(), kern.support, False), n, kern, variant, True)
    assert np.abs(without - want_mom).max() > 1e-3 * np.abs(want_mom).max()


@pytest.mark.parametrize("morris", [False, True])
def test_no_slip_images_reverse_the_velocity_about_the_lid(morris):
    """No slip without shifting: the momentum equals the fluid kernel's over images carrying 2 u_b - u_j
    (the continuity uses the other mirroring, so only the momentum is compared), with either viscous
    operator."""
    f, dx = fluid_in_box(np.random.default_rng(11))
    kern = make_kernel("wendland_c6", 2, 2.0 * dx)
    _, d_mom, _ = ghost_rates(f, kern, 1, False, True, morris)
    _, want = fluid_rates(explicit_images(f, box_walls(), kern.support, True), len(f["pos"]), kern, 1, False,
                          morris)
    assert np.abs(d_mom - want).max() < 1e-10 * np.abs(want).max()
    _, free_slip, _ = ghost_rates(f, kern, 1, False, False, morris)
    assert np.abs(free_slip - want).max() > 1e-3 * np.abs(want).max()  # the two mirrorings differ


def test_images_complete_the_concentration_gradient_and_the_renormalisation_matrix():
    """On a lattice filling the box, grad C with the images vanishes to round-off at the walls and corners
    (without them it points out of the fluid there), and the free-surface detection's renormalisation
    matrix is everywhere the one in the middle of the box (without them its smallest eigenvalue, lambda,
    falls to about half at a wall)."""
    n_side = 12
    dx = 1.0 / n_side
    g = (np.stack(np.meshgrid(np.arange(n_side), np.arange(n_side), indexing="ij"), -1).reshape(-1, 2) + 0.5) * dx
    pos, vol = np.ascontiguousarray(g), np.full(len(g), dx * dx)
    kern = make_kernel("wendland_c6", 2, 2.0 * dx)
    ptr, idx = build_neighbour_lists(pos, len(pos), 1.1 * kern.support)
    grad = np.zeros_like(pos)
    corrected_grad_c(pos, vol, ptr, idx, kern.params, 0.0, 1.0, 1.0, grad)
    truncated = np.abs(grad).max()
    rows = np.arange(len(pos))
    images = ghost_images(pos, np.zeros(len(pos), np.int8), rows, box_walls(), ptr, idx, kern.support)
    ghost_grad_c(pos, vol, rows, *images, box_walls()["axis"], box_walls()["coord"], kern.params, 0.0, 1.0, 1.0,
                 grad, NO_MATRIX)
    assert truncated > 1.0 and np.abs(grad).max() < 1e-10 * truncated
    mat, grad = np.zeros((len(pos), 2, 2)), np.zeros_like(pos)
    renormalisation_and_grad_c(pos, vol, ptr, idx, kern.params, mat, grad)
    middle = mat[np.argmin(np.linalg.norm(pos - 0.5, axis=1))]
    assert np.abs(mat - middle).max() > 0.3 * np.abs(middle).max()
    ghost_grad_c(pos, vol, rows, *images, box_walls()["axis"], box_walls()["coord"], kern.params, 0.0, 1.0, 1.0,
                 grad, mat)
    assert np.abs(mat - middle).max() < 1e-10 * np.abs(middle).max() and np.abs(grad).max() < 1e-10 * truncated



@pytest.mark.parametrize("variant", [RIEMANN_WALLS, RIEMANN_WALLS_LOW])
@pytest.mark.parametrize("u_y", [-0.3, 0.3])
def test_the_riemann_wall_is_the_partial_riemann_problem(variant, u_y):
    """The Riemann SPH-ALE scheme's wall pair: a particle at s above a wall at rest meets its own image at -s
    (its only one). Its momentum rate is -V_i 2 p* F(2 s) V_i x_ig with Marongiu's partial Riemann problem,
    p* = p_i + rho c0 (u_i . n) (n = -y into the wall) for the acoustic solver, Zhang et al.'s
    p_i + rho beta (u_l - u_r) / 2, beta = min(3 max(u_l - u_r, 0), c0) for the low-dissipation one (u_l - u_r =
    -2 u_y); its volume rate V_i (v0_g - v0_i) . F V_i x_ig with the transport velocity's normal part reversed;
    nothing tangential, and no viscosity (mu = 0)."""
    dx, s = 1.0 / 12, 0.3 / 12
    kern = make_kernel("wendland_c6", 2, 2.0 * dx)
    rho = 1.02
    f = dict(pos=np.array([[0.5, s]]), vol=np.array([dx * dx]), rho=np.array([rho]),
             prs=np.array([C0 * C0 * (rho - RHO0)]), vel=np.array([[0.4, u_y]]), du=np.array([[0.05, -0.02]]))
    walls = box_walls()
    ptr, idx = build_neighbour_lists(f["pos"], 1, 1.1 * kern.support)
    rows = np.arange(1)
    images = ghost_images(f["pos"], np.zeros(1, dtype=np.int8), rows, walls, ptr, idx, kern.support)
    d_vol, d_mom = np.zeros(1), np.zeros((1, 2))
    ghost_rhs(f["pos"], f["vol"], f["rho"], f["vel"], f["du"], f["prs"], rows, *images, walls["axis"],
              walls["coord"], walls["velocity"], True, kern.params, C0, RHO0, False, 0.0, False, np.zeros(2), variant,
              True, np.zeros(1, dtype=np.int8), d_vol, d_mom)
    jump = -2.0 * u_y
    if variant == RIEMANN_WALLS:
        p_star = f["prs"][0] + rho * C0 * (-u_y)
    else:
        p_star = f["prs"][0] + 0.5 * rho * min(3.0 * max(jump, 0.0), C0) * jump
    fv = float(kern.radial(2.0 * s)) * f["vol"][0]
    v_i = f["vol"][0]
    assert d_mom[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert d_mom[0, 1] == pytest.approx(-v_i * 2.0 * p_star * fv * 2.0 * s, rel=1e-12)
    v0_y = u_y + f["du"][0, 1]
    assert d_vol[0] == pytest.approx(v_i * (-2.0 * v0_y) * fv * 2.0 * s, rel=1e-12)
    # the acoustic solver's p* against the module's own solver, called with the pair's states
    if variant == RIEMANN_WALLS:
        assert riemann.acoustic_riemann(rho, -u_y, rho, u_y, C0, RHO0, False)[2] == pytest.approx(p_star, rel=1e-14)
