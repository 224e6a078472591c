"""The delta-ALE-SPH kernels against a brute-force numpy evaluation of seed 001 eq. 11-15 over all pairs.

The numba kernels skip the lists' skin, cache the support's pairs between their two passes and are
specialised per dimension; this reference does none of that.
"""

import numpy as np
import pytest

from psph.compute import fluid
from tests.helpers import perturbed_lattice


def reference(pos, vol, rho, mass, vel, du, prs, kp_kernel, c0, delta, delta_m, mu, gravity, variant, switch,
              kind, fluid_only, morris=False, diffusive=None):
    """(grad_rho, d_rho, d_mass, d_mom) from the formulas of compute/fluid.py's docstring, over all pairs
    (the diffusive terms over the pairs of two `diffusive` particles, if given)."""
    n, d = pos.shape
    x = pos[:, None, :] - pos[None, :, :]  # x_ij
    r = np.sqrt((x * x).sum(axis=2))
    use = (r > 0.0) & (r < kp_kernel.support)
    if fluid_only:
        use &= (kind[:, None] == 0) & (kind[None, :] == 0)
    f = np.where(use, kp_kernel.radial(r), 0.0)
    w = f[:, :, None] * x * vol[None, :, None]  # grad_i W_ij V_j
    m = -np.einsum("ija,ijb->iab", x, w)
    g = np.einsum("ij,ija->ia", rho[None, :] - rho[:, None], w)
    m[kind != 0] = np.eye(d) if fluid_only else m[kind != 0]  # solid rows carry no field
    grad_rho = np.linalg.solve(m, g[:, :, None])[:, :, 0]
    dvel = vel[None, :, :] - vel[:, None, :]  # u_j - u_i
    div_u = np.einsum("ija,ija->i", dvel, w)
    pp = np.where((switch & (prs < 0.0))[:, None], prs[None, :] - prs[:, None], prs[None, :] + prs[:, None])
    gp = np.einsum("ij,ija->ia", pp, w)
    r2 = np.where(use, r * r, 1.0)
    if morris:  # 2 sum_j (u_j - u_i) F_ij V_j, F_ij = -f
        vs = -2.0 * np.einsum("ij,ija->ia", f * vol[None, :], dvel)
    else:  # sum_j pi_ij grad_i W_ij V_j
        vs = np.einsum("ij,ija->ia", 2.0 * (d + 2) * np.einsum("ija,ija->ij", dvel, -x) / r2, w)
    psi = rho[None, :] - rho[:, None] + 0.5 * np.einsum("ija,ija->ij", grad_rho[:, None] + grad_rho[None, :], x)
    h = kp_kernel.h
    on = np.ones((n, n)) if diffusive is None else diffusive[:, None] & diffusive[None, :]
    diff_rho = 2.0 * delta * h * c0 * (on * psi * -f * vol[None, :]).sum(axis=1)
    diff_m = 2.0 * delta_m * h * c0 * (on * (mass[None, :] - mass[:, None]) * -f * np.sqrt(vol[:, None] * vol)).sum(1)
    ddj = np.einsum("ja,ija->ij", du, w)  # du_j . grad_i W_ij V_j
    ddi = np.einsum("ia,ija->ij", du, w)
    div_du = np.einsum("ija,ija->i", du[None, :, :] - du[:, None, :], w)
    div_rdu = (rho[None, :] * ddj + rho[:, None] * ddi).sum(axis=1)
    if variant == 0:
        sh = np.einsum("j,ja,ij->ia", rho, vel, ddj) + np.einsum("i,ia,ij->ia", rho, vel, ddi)
    else:
        sh = np.einsum("ja,ij->ia", vel, ddj) + np.einsum("ia,ij->ia", vel, ddi)
    d_rho = -rho * (div_u + div_du) + div_rdu + diff_rho
    if variant == 0:
        d_mass = vol * div_rdu + diff_m
        d_mom = vol[:, None] * (-gp + mu * vs + sh) + mass[:, None] * gravity
    else:
        d_mass = np.zeros(n)
        d_mom = (-gp + mu * vs) / rho[:, None] + gravity + sh - vel * div_du[:, None]
    if fluid_only:
        solid = kind != 0
        grad_rho[solid] = 0.0
        d_rho[solid] = d_mass[solid] = d_mom[solid] = 0.0
    return grad_rho, d_rho, d_mass, d_mom


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("variant", [0, 1])
@pytest.mark.parametrize("walls", [False, True])
@pytest.mark.parametrize("morris", [False, True])
def test_kernels_match_brute_force_sums(dim, variant, walls, morris):
    rng = np.random.default_rng(dim * 10 + variant + 5 * walls)
    pos, vol, kern, ptr, idx = perturbed_lattice(rng, dim, {1: 40, 2: 9, 3: 5}[dim])
    n = len(pos)
    rho = 1.0 + 0.05 * rng.standard_normal(n)
    mass = rho * vol
    vel, du = rng.standard_normal((n, dim)), 0.1 * rng.standard_normal((n, dim))
    prs = rng.standard_normal(n)  # both signs: the tensile switch acts on some rows
    kind = np.where(rng.random(n) < (0.2 if walls else 0.0), 1, 0).astype(np.int8)
    gravity = np.array([0.3, -1.0, 0.2])[:dim]
    consts = dict(c0=10.0, delta=0.1, delta_m=0.05, mu=0.01, gravity=gravity, variant=variant)
    grad_rho = np.zeros((n, dim))
    pairs = fluid.PairCache()
    fluid.renormalised_gradient(pos, vol, rho, ptr, idx, kern.params, kind, walls, grad_rho, pairs)
    want = reference(pos, vol, rho, mass, vel, du, prs, kern, switch=True, kind=kind, fluid_only=walls,
                     morris=morris, **consts)
    assert np.abs(grad_rho - want[0]).max() < 1e-9 * np.abs(want[0]).max()
    got = np.zeros(n), np.zeros(n), np.zeros((n, dim))
    fluid.delta_ale_rhs(pos, vol, rho, mass, vel, du, prs, grad_rho, pairs, kern.params, consts["c0"],
                        consts["delta"], consts["delta_m"], consts["mu"], gravity, variant, True, True, kind,
                        walls, *got, morris=morris)
    for name, a, b in zip(("d_rho", "d_mass", "d_mom"), got, want[1:]):
        assert np.abs(a - b).max() <= 1e-10 * max(np.abs(b).max(), 1e-300), name


@pytest.mark.parametrize("dim", [2, 3])
def test_diffusion_switch_acts_on_pairs_and_keeps_the_mass(dim):
    """free_surface.lambda_diffusion (seed 001 section 6.3): D^rho and D^m act on the pairs of two particles
    that take part; a particle out of it gets none, the others lose only their pairs with it, and the total
    mass rate stays zero (D^m antisymmetric pair by pair)."""
    rng = np.random.default_rng(21 + dim)
    pos, vol, kern, ptr, idx = perturbed_lattice(rng, dim, {2: 9, 3: 5}[dim])
    n = len(pos)
    rho = 1.0 + 0.05 * rng.standard_normal(n)
    mass = rho * vol * (1.0 + 0.1 * rng.standard_normal(n))
    vel, du = rng.standard_normal((n, dim)), 0.1 * rng.standard_normal((n, dim))
    prs, kind = rng.standard_normal(n), np.zeros(n, dtype=np.int8)
    diffusive = (rng.random(n) > 0.3).astype(np.int8)
    consts = dict(c0=10.0, delta=0.1, delta_m=0.05, mu=0.01, gravity=np.zeros(dim), variant=0)
    grad_rho, pairs = np.zeros((n, dim)), fluid.PairCache()
    fluid.renormalised_gradient(pos, vol, rho, ptr, idx, kern.params, kind, False, grad_rho, pairs)
    got = {}
    for name, mask in (("switch", diffusive), ("none", np.zeros(n, dtype=np.int8)), ("all", True)):
        got[name] = np.zeros(n), np.zeros(n), np.zeros((n, dim))
        fluid.delta_ale_rhs(pos, vol, rho, mass, vel, du, prs, grad_rho, pairs, kern.params, consts["c0"],
                            consts["delta"], consts["delta_m"], consts["mu"], consts["gravity"], 0, True, True,
                            kind, False, *got[name], diffusive=mask)
    want = reference(pos, vol, rho, mass, vel, du, prs, kern, switch=True, kind=kind, fluid_only=False,
                     diffusive=diffusive.astype(bool), **consts)
    for a, b in zip(got["switch"], want[1:]):
        assert np.abs(a - b).max() <= 1e-10 * np.abs(b).max()
    out = diffusive == 0
    for a, b in zip(got["switch"], got["none"]):
        assert np.array_equal(a[out], b[out])  # no diffusion on a particle out of it
    assert np.abs(got["switch"][0] - got["all"][0])[~out].max() > 1e-3 * np.abs(got["all"][0]).max()
    assert abs(got["switch"][1].sum()) < 1e-13 * np.abs(got["switch"][1]).sum()


@pytest.mark.parametrize("dim", [2, 3])
def test_density_diffusion_vanishes_on_linear_fields_damps_a_bump_and_keeps_the_mass(dim):
    """D^rho (seed 001 eq. 14) by its properties rather than by its formula: with psi_ji's correction by the
    renormalised gradients (eq. 15) it vanishes on a linear density field on a disordered lattice, where the
    plain difference rho_j - rho_i does not; it lowers a density maximum; sum_i V_i D^rho_i = 0."""
    rng = np.random.default_rng(5 + dim)
    pos, vol, kern, ptr, idx = perturbed_lattice(rng, dim, {2: 24, 3: 11}[dim])
    n = len(pos)
    kind, zero = np.zeros(n, dtype=np.int8), np.zeros((n, dim))

    def diffusion(rho, corrected=True):
        grad_rho, pairs = np.zeros((n, dim)), fluid.PairCache()
        fluid.renormalised_gradient(pos, vol, rho, ptr, idx, kern.params, kind, False, grad_rho, pairs)
        out = np.zeros(n), np.zeros(n), np.zeros((n, dim))
        fluid.delta_ale_rhs(pos, vol, rho, rho * vol, zero, zero, np.zeros(n), grad_rho if corrected else zero,
                            pairs, kern.params, 10.0, 0.1, 0.0, 0.0, np.zeros(dim), 1, False, False, kind, False,
                            *out)
        return out[0]  # no velocity, pressure or viscosity: d rho / dt = D^rho

    inner = np.all((pos > kern.support) & (pos < 1.0 - 1.2 * kern.support), axis=1)
    linear = 1.0 + 0.3 * pos[:, 0] - 0.2 * pos[:, 1]
    scale = 2.0 * 0.1 * kern.h * 10.0 * 0.3 / kern.h  # 2 delta h c0 |grad rho| / h: one pair's order
    assert np.abs(diffusion(linear)[inner]).max() < 1e-10 * scale
    assert np.abs(diffusion(linear, corrected=False)[inner]).max() > 1e-3 * scale
    bump = 1.0 + 0.01 * np.exp(-((pos - 0.5) ** 2).sum(axis=1) / 0.02)
    d = diffusion(bump)
    assert d[np.argmax(bump)] < 0.0
    assert abs(vol @ d) < 1e-12 * (vol @ np.abs(d))


@pytest.mark.parametrize("dim", [2, 3])
def test_shifting_terms_change_the_total_volume_by_minus_two_v_du_grad_c(dim):
    """delta-ALE-SPH (seed 001 eq. 12-13): the du terms change V_i = m_i / rho_i by V_i <div du>_i, and with
    <div du> a difference they add up to sum_i V_i <div du>_i = -2 sum_i V_i du_i . grad C_i (grad C_i =
    sum_j grad_i W_ij V_j): a volume source wherever the shifting works against a concentration gradient,
    the budget run_scripts/volume_budget.py measures near walls."""
    rng = np.random.default_rng(7 + dim)
    pos, vol, kern, ptr, idx = perturbed_lattice(rng, dim, {2: 10, 3: 5}[dim])
    n = len(pos)
    rho = 1.0 + 0.05 * rng.standard_normal(n)
    mass = rho * vol
    vel, du = rng.standard_normal((n, dim)), 0.1 * rng.standard_normal((n, dim))
    prs, kind = rng.standard_normal(n), np.zeros(n, dtype=np.int8)
    grad_rho, pairs = np.zeros((n, dim)), fluid.PairCache()
    fluid.renormalised_gradient(pos, vol, rho, ptr, idx, kern.params, kind, False, grad_rho, pairs)
    dv = {}
    for shifted in (True, False):
        d_rho, d_mass = np.zeros(n), np.zeros(n)
        fluid.delta_ale_rhs(pos, vol, rho, mass, vel, du, prs, grad_rho, pairs, kern.params, 10.0, 0.1, 0.05,
                            0.01, np.zeros(dim), 0, shifted, True, kind, False, d_rho, d_mass, np.zeros((n, dim)))
        dv[shifted] = vol * (d_mass / mass - d_rho / rho)
    x = pos[:, None, :] - pos[None, :, :]
    r = np.sqrt((x * x).sum(axis=2))
    f = np.where((r > 0.0) & (r < kern.support), kern.radial(r), 0.0)
    grad_c = np.einsum("ij,ija->ia", f * vol[None, :], x)
    source = -2.0 * (vol * (du * grad_c).sum(axis=1)).sum()
    assert abs(source) > 1e-3 * np.abs(dv[True] - dv[False]).sum()  # not a vanishing identity
    assert abs((dv[True] - dv[False]).sum() - source) < 1e-12 * np.abs(dv[True] - dv[False]).sum()


def lattice(m):
    """The m x m square lattice of the unit box: positions and volumes."""
    g = (np.arange(m) + 0.5) / m
    return np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2), np.full(m * m, 1.0 / m**2)


def lattice_nu_eff(h_over_dx):
    """nu_eff / nu of eq. 11 on a divergence-free field with lap u = -2 k^2 u (Taylor-Green) at leading order
    in dx, from the stencil's fourth moments: a_1 = c (M_1111 - M_1122) d^2 u_1/dx^2 + ..., M_abcd =
    sum_j V_j W'(r)/r^3 x_a x_b x_c x_d over the square lattice's offsets, against the same moments
    integrated over the plane (polar quadrature: M_1111 - M_1122 = pi/2 int W'(r) r^2 dr)."""
    from scipy.integrate import quad

    from psph.compute.smoothing import make_kernel

    kern = make_kernel("wendland_c6", 2, h_over_dx)  # dx = 1
    m = int(np.ceil(kern.support)) + 1
    x, y = np.meshgrid(np.arange(-m, m + 1.0), np.arange(-m, m + 1.0), indexing="ij")
    r = np.hypot(x, y)
    inside = (r > 0.0) & (r < kern.support)
    g = kern.radial(r[inside]) / r[inside] ** 2  # radial = W'(r) / r
    lattice_moment = (g * x[inside] ** 2 * (x[inside] ** 2 - y[inside] ** 2)).sum()
    plane = quad(lambda s: float(kern.radial(np.array([s]))[0]) * s**3, 0.0, kern.support, epsrel=1e-12)[0]
    return lattice_moment / (0.5 * np.pi * plane)


def test_viscous_operator_has_a_lattice_error_that_refinement_does_not_remove():
    """The floor of the Taylor-Green convergence (run_scripts/tgv_operator_error.py): on a square lattice the
    viscous operator of seed 001 eq. 11 (K = 2(d + 2)) dissipates the vortex with the nu_eff / nu its
    stencil's fourth moments predict (1.090 at h/dx = 2, 1.018 at 3: the lattice's anisotropy, a quadrature
    error, not a smoothing error), at every resolution, while the pressure gradient converges at second
    order."""
    from psph.studies import tgv_operator_errors

    coarse, fine = tgv_operator_errors(*lattice(40), 2.0), tgv_operator_errors(*lattice(80), 2.0)
    predicted = lattice_nu_eff(2.0)
    assert predicted > 1.05  # the anisotropy is not small
    assert abs(fine["nu_eff_ratio"] - predicted) < 0.003  # 1.0886 against 1.0901 (dx^2 terms left)
    assert abs(fine["nu_eff_ratio"] - predicted) < abs(coarse["nu_eff_ratio"] - predicted) / 2.5
    assert abs(fine["viscous_rms"] - (fine["nu_eff_ratio"] - 1.0)) < 1e-6  # a uniform factor on the lattice
    assert 1.8 < np.log2(coarse["grad_p_rms"] / fine["grad_p_rms"]) < 2.1
    # 1.0151 against 1.0183: the h^2 terms are larger with h = 3 dx
    assert abs(tgv_operator_errors(*lattice(80), 3.0)["nu_eff_ratio"] - lattice_nu_eff(3.0)) < 0.005


def test_morris_viscous_operator_converges_where_eq_11_stalls():
    """physics.viscosity = "morris": 2 sum_j (u_j - u_i) F_ij V_j (Morris et al. 1997). On the square lattice
    its stencil moment -sum_j f x_ji (x) x_ji V_j is isotropic by symmetry, so it has no anisotropy error: on
    the Taylor-Green vortex at h/dx = 2, nu_eff / nu goes to 1 under refinement (0.991 at 40 x 40, 0.997 at
    80 x 80), where eq. 11 stays at 1.09 (test above); its pointwise error also falls."""
    from psph.studies import tgv_operator_errors

    coarse, fine = (tgv_operator_errors(*lattice(m), 2.0, morris=True) for m in (40, 80))
    assert 0.98 < coarse["nu_eff_ratio"] < 1.0 and abs(fine["nu_eff_ratio"] - 1.0) < 0.004
    assert abs(fine["nu_eff_ratio"] - 1.0) < abs(coarse["nu_eff_ratio"] - 1.0) / 2.5
    assert fine["viscous_rms"] < coarse["viscous_rms"] / 2.5
    assert tgv_operator_errors(*lattice(80), 2.0)["viscous_rms"] > 20 * fine["viscous_rms"]


@pytest.mark.parametrize("dim", [2, 3])
def test_morris_operator_on_a_linear_field_is_two_g_dot_grad_c(dim):
    """Why IIPS and Morris' operator go together: on u = G x + c the operator gives, exactly,
    2 sum_j (u_j - u_i) F_ij V_j = -2 sum_j f V_j G x_ji = 2 G grad C_i (grad C_i = sum_j V_j f x_ij), its
    O(1/h) inconsistency on an irregular distribution. IIPS drives grad C to zero, and with it this term;
    eq. 11 has no such link."""
    rng = np.random.default_rng(7 + dim)
    pos, vol, kern, ptr, idx = perturbed_lattice(rng, dim, {2: 10, 3: 5}[dim])
    n = len(pos)
    g = rng.standard_normal((dim, dim))
    vel = np.ascontiguousarray(pos @ g.T + rng.standard_normal(dim))
    rho, kind = np.ones(n), np.zeros(n, np.int8)
    pairs, grad_rho = fluid.PairCache(), np.zeros((n, dim))
    fluid.renormalised_gradient(pos, vol, rho, ptr, idx, kern.params, kind, False, grad_rho, pairs)
    d_mom = np.zeros((n, dim))
    fluid.delta_ale_rhs(pos, vol, rho, vol, vel, np.zeros((n, dim)), np.zeros(n), grad_rho, pairs, kern.params,
                        1.0, 0.0, 0.0, 1.0, np.zeros(dim), 1, False, False, kind, False, np.zeros(n), np.zeros(n),
                        d_mom, morris=True)
    x = pos[:, None, :] - pos[None, :, :]
    r = np.sqrt((x * x).sum(axis=2))
    f = np.where((r > 0) & (r < kern.support), kern.radial(r), 0.0)
    grad_c = np.einsum("ij,j,ija->ia", f, vol, x)
    want = 2.0 * grad_c @ g.T
    assert np.abs(want).max() > 1.0  # not a vanishing identity
    assert np.abs(d_mom - want).max() < 1e-10 * np.abs(want).max()
