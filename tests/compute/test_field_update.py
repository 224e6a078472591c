"""IIPS field updates: NFTS conserves mass and momentum exactly and keeps uniform states uniform (the sign
analysis of psph/compute/field_update.py); MLS reproduces linear / quadratic fields exactly."""

import numpy as np
import pytest

from psph.compute.field_update import mls_interpolate, nfts_increments
from psph.compute.neighbours import build_cross_lists, build_neighbour_lists
from psph.compute.smoothing import make_kernel


def cloud(n=14, jitter=0.2, seed=0):
    g = (np.arange(n) + 0.5) / n
    pos = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    pos += np.random.default_rng(seed).normal(0, jitter / n, pos.shape)
    k = make_kernel("wendland_c6", 2, 2.0 / n)
    ptr, idx = build_neighbour_lists(pos, len(pos), k.support)
    return pos, np.full(len(pos), 1.0 / n**2), ptr, idx, k


def increments(pos, vol, rho, vel, step, ptr, idx, k):
    n = len(pos)
    dv, dm, dp = np.zeros(n), np.zeros(n), np.zeros((n, 2))
    nfts_increments(pos, vol, rho, vel, step, np.zeros(n, np.int8), np.zeros((1, 2)), ptr, idx,
                    k.params, dv, dm, dp)
    return dv, dm, dp


def test_nfts_conserves_mass_and_momentum_exactly():
    pos, vol, ptr, idx, k = cloud()
    rng = np.random.default_rng(1)
    rho = 1.0 + 0.01 * rng.normal(size=len(pos))
    vel = rng.normal(size=(len(pos), 2))
    step = 0.01 / 14 * rng.normal(size=(len(pos), 2))
    dv, dm, dp = increments(pos, vol, rho, vel, step, ptr, idx, k)
    assert abs(dm.sum()) < 1e-15 * np.abs(dm).sum() * 1e3
    assert np.abs(dp.sum(axis=0)).max() < 1e-12 * np.abs(dp).sum()
    assert abs(dv.sum()) > 1e-9 * np.abs(dv).sum()  # total volume is not conserved (seed 001 eq. 21)


def test_nfts_next_to_a_wall_conserves_mass_and_squeezes_volume():
    """Solid neighbours (the bottom rows, wall normal +y) are clones with mirrored steps: a wall pair changes
    the fluid particle's volume by -2 V_i (s_i . n) (n . grad W_ij) V_j and adds no mass or momentum flux,
    so the fluid's mass and momentum are conserved to round-off (the tangential flux of the mirrored pair
    made mass before)."""
    pos, vol, ptr, idx, k = cloud(jitter=0.1)
    n = len(pos)
    kind = np.where(pos[:, 1] < 0.25, 1, 0).astype(np.int8)
    normal = np.tile([0.0, 1.0], (n, 1))
    rng = np.random.default_rng(2)
    rho = 1.0 + 0.01 * rng.normal(size=n)
    vel = rng.normal(size=(n, 2))
    step = 0.01 / 14 * rng.normal(size=(n, 2))
    dv, dm, dp = np.zeros(n), np.zeros(n), np.zeros((n, 2))
    nfts_increments(pos, vol, rho, vel, step, kind, normal, ptr, idx, k.params, dv, dm, dp)
    fluid = kind == 0
    assert np.abs(dm[~fluid]).max() == 0.0 and np.abs(dv[~fluid]).max() == 0.0
    assert abs(dm[fluid].sum()) < 1e-13 * np.abs(dm).sum()
    assert np.abs(dp[fluid].sum(axis=0)).max() < 1e-12 * np.abs(dp).sum()
    # the volume change of the fluid particles, pair by pair, with the clone's mirrored step
    expected = np.zeros(n)
    for i in np.flatnonzero(fluid):
        for j in idx[ptr[i]:ptr[i + 1]]:
            x = pos[i] - pos[j]
            grad = k.gradient(x)[0] * vol[j]
            s_j = step[j] if fluid[j] else step[i] - 2.0 * step[i][1] * np.array([0.0, 1.0])
            expected[i] += vol[i] * (s_j - step[i]) @ grad
    near = fluid & (pos[:, 1] < 0.25 + k.support)
    assert np.allclose(dv[fluid], expected[fluid], rtol=1e-12, atol=1e-20)
    assert np.abs(dv[near]).max() > 1e-8


def test_nfts_keeps_uniform_states_uniform():
    """Uniform density and velocity: the mass change equals rho x the volume change up to the grad C term,
    and the velocity is unchanged exactly (the thesis' printed minus sign would double the volume change)."""
    pos, vol, ptr, idx, k = cloud(jitter=0.0)
    rho = np.full(len(pos), 1.3)
    vel = np.tile([0.4, -0.2], (len(pos), 1))
    step = 0.01 / 14 * np.stack([np.sin(7 * pos[:, 0]), np.cos(5 * pos[:, 1])], 1)  # div(step) != 0
    dv, dm, dp = increments(pos, vol, rho, vel, step, ptr, idx, k)
    inner = np.all((pos > 0.3) & (pos < 0.7), axis=1)  # full supports on the lattice (grad C = 0)
    assert np.allclose(dm[inner], 1.3 * dv[inner], rtol=1e-10, atol=1e-18)
    new_vel = ((vol * rho + dm)[:, None] * 0 + (vol * rho)[:, None] * vel + dp) / (vol * rho + dm)[:, None]
    assert np.allclose(new_vel, vel, atol=1e-14)
    assert np.abs(dv[inner]).max() > 1e-8  # the volumes really change


@pytest.mark.parametrize("order,degree", [(1, 1), (2, 2)])
def test_mls_reproduces_polynomials(order, degree):
    pos, vol, _, _, k = cloud(jitter=0.25)
    new = pos + np.random.default_rng(3).normal(0, 0.05 / 14, pos.shape)
    inner = np.all((new > 0.3) & (new < 0.7), axis=1)

    def field(x):
        lin = 1.0 + 2.0 * x[:, 0] - 3.0 * x[:, 1]
        return lin + (4.0 * x[:, 0] * x[:, 1] - x[:, 1] ** 2 if degree == 2 else 0.0)

    ptr, idx = build_cross_lists(new, pos, k.support)
    out = np.zeros((len(new), 1))
    mls_interpolate(new, pos, vol, field(pos)[:, None].copy(), ptr, idx, k.params, order, out)
    assert np.allclose(out[inner, 0], field(new)[inner], atol=1e-9)
    if order == 1:  # first order does not reproduce a quadratic
        quad = (pos[:, 0] ** 2)[:, None].copy()
        mls_interpolate(new, pos, vol, quad, ptr, idx, k.params, 1, out)
        assert not np.allclose(out[inner, 0], new[inner, 0] ** 2, atol=1e-6)


def mls_by_least_squares(new, pos, vol, fields, k, order):
    """The MLS fit of thesis eq. 9.8-9.9 by numpy: solve sum_j W_ij V_j P_j P_j^T a = sum_j W_ij V_j P_j phi_j."""
    h = k.h
    out = np.full((len(new), fields.shape[1]), np.nan)
    for i, x in enumerate(new):
        xij = x - pos
        w = k.value(np.linalg.norm(xij, axis=1)) * vol
        terms = [np.ones(len(pos)), xij[:, 0] / h, xij[:, 1] / h]
        if order == 2:
            terms += [xij[:, 0] ** 2 / h**2, xij[:, 0] * xij[:, 1] / h**2, xij[:, 1] ** 2 / h**2]
        p = np.stack(terms, axis=1)
        out[i] = np.linalg.solve((p * w[:, None]).T @ p, (p * w[:, None]).T @ fields)[0]
    return out


@pytest.mark.parametrize("order", [1, 2])
def test_mls_equals_the_least_squares_fit_of_every_field(order):
    """One solve per particle for all fields (the first column of the inverse moment matrix) gives the fit of
    each field on its own, weighted by the old volumes (eq. 9.8: W_ij omega_j; unequal here, which a field-update
    audit's mutant dropping them needed to be caught)."""
    pos, vol, _, _, k = cloud(jitter=0.25)
    vol = vol * (0.6 + 0.8 * np.random.default_rng(7).random(len(vol)))
    new = pos + np.random.default_rng(5).normal(0, 0.1 / 14, pos.shape)
    fields = np.random.default_rng(6).normal(size=(len(pos), 3))
    ptr, idx = build_cross_lists(new, pos, k.support)
    out = np.zeros((len(new), 3))
    mls_interpolate(new, pos, vol, fields, ptr, idx, k.params, order, out)
    assert np.allclose(out, mls_by_least_squares(new, pos, vol, fields, k, order), rtol=1e-9, atol=1e-12)


def test_mls_falls_back_to_the_shepard_average_and_to_nan():
    """Old particles on a line make every moment matrix above order 0 singular: the Shepard average is taken;
    a new particle with no old one in reach gets NaN (which the field update reports). The fallback is counted
    (the run's summary reports the count), the NaN is not."""
    k = make_kernel("wendland_c6", 2, 0.1)
    pos = np.stack([np.linspace(-0.15, 0.15, 7), np.zeros(7)], axis=1)
    vol, phi = np.full(7, 0.01), np.linspace(1.0, 2.0, 7)[:, None] ** 2
    new = np.array([[0.01, 0.02], [5.0, 5.0]])
    ptr, idx = build_cross_lists(new, pos, k.support)
    for order in (1, 2):
        out = np.zeros((2, 1))
        assert mls_interpolate(new, pos, vol, phi.copy(), ptr, idx, k.params, order, out) == 1
        assert mls_interpolate(new[:1], pos, vol, phi.copy(), ptr[:2], idx, k.params, 0, out) == 0
        w = k.value(np.linalg.norm(new[0] - pos, axis=1)) * vol
        assert out[0, 0] == pytest.approx((w @ phi[:, 0]) / w.sum(), rel=1e-12)
        assert np.isnan(out[1, 0])


@pytest.mark.parametrize("order", [1, 2])
def test_mls_on_a_nearly_collinear_support_falls_back_rather_than_amplify(order):
    """Old particles on a line jittered by 1e-4 h pass the pivot test, and the fit extrapolated a field of
    order 1 to an error of 154 half a dx off the line (a field-update audit). Its Lebesgue constant sum_j |c_j|
    is then far above LEBESGUE_MAX: the fit falls back (to the Shepard average, whose constant is 1), and
    counts it."""
    from psph.compute.field_update import LEBESGUE_MAX

    dx = 0.1
    k = make_kernel("wendland_c6", 2, 2 * dx)
    xs = np.arange(-6, 7) * dx
    pos = np.stack([xs, 1e-4 * k.h * np.random.default_rng(0).normal(size=len(xs))], axis=1)
    vol = np.full(len(pos), dx * dx)

    def field(x):
        return np.sin(2 * np.pi * x[:, 0]) + np.cos(2 * np.pi * x[:, 1])

    new = np.array([[0.03, 0.5 * dx]])
    ptr, idx = build_cross_lists(new, pos, k.support)
    out = np.zeros((1, 1))
    assert mls_interpolate(new, pos, vol, field(pos)[:, None].copy(), ptr, idx, k.params, order, out) == 1
    assert abs(out[0, 0] - field(new)[0]) < 0.05
    fit = mls_by_least_squares(new, pos, vol, field(pos)[:, None], k, order)  # what the fit would have given
    assert abs(fit[0, 0] - field(new)[0]) > 1.0 and LEBESGUE_MAX == 20.0


def test_mls_of_order_2_on_two_rows_falls_back_to_order_1():
    """Two rows of old particles: the quadratic's moment matrix is singular across them, the linear one's is
    not: a linear field is still reproduced exactly, and the one fallback counted."""
    dx = 0.1
    k = make_kernel("wendland_c6", 2, 2 * dx)
    g = np.arange(-6, 7) * dx
    pos = np.stack(np.meshgrid(g, [0.0, dx], indexing="ij"), -1).reshape(-1, 2)
    vol = np.full(len(pos), dx * dx)
    new = np.array([[0.02, 0.04]])
    phi = (1.0 + 2.0 * pos[:, 0] - 3.0 * pos[:, 1])[:, None].copy()
    ptr, idx = build_cross_lists(new, pos, k.support)
    out = np.zeros((1, 1))
    assert mls_interpolate(new, pos, vol, phi, ptr, idx, k.params, 2, out) == 1
    assert out[0, 0] == pytest.approx(1.0 + 0.04 - 0.12, abs=1e-12)


def test_cross_lists_match_brute_force():
    rng = np.random.default_rng(4)
    data, query = rng.uniform(0, 1, (300, 2)), rng.uniform(0, 1, (200, 2))
    ptr, idx = build_cross_lists(query, data, 0.1)
    d2 = ((query[:, None] - data[None]) ** 2).sum(-1)
    for i in range(len(query)):
        assert set(idx[ptr[i]:ptr[i + 1]]) == set(np.flatnonzero(d2[i] < 0.01))
