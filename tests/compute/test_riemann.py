"""The Riemann SPH-ALE kernels (thesis 000 eq. 5.48-5.49, psph.compute.riemann): the MUSCL gradients, the
linearised Riemann solver's jump relations and symmetry, conservation pair by pair, and the centred fluxes
of eq. 5.45 where the reconstruction leaves no jump."""

import numpy as np
import pytest

from psph.compute import fluid, riemann
from tests.helpers import perturbed_lattice


def _setup(dim, seed, n_side=None):
    rng = np.random.default_rng(seed)
    pos, vol, kern, ptr, idx = perturbed_lattice(rng, dim, n_side or {1: 40, 2: 9, 3: 5}[dim])
    pairs = fluid.PairCache()
    n = len(pos)
    fluid.renormalised_gradient(pos, vol, np.zeros(n), ptr, idx, kern.params, np.zeros(n, dtype=np.int8), False,
                                np.zeros((n, dim)), pairs)
    return rng, pos, vol, kern, pairs


def _rhs(pos, vol, rho, vel, v0, pairs, kern, tait=False, mu=0.0, morris=False, gravity=None, limited=True,
         low=False):
    n, dim = pos.shape
    grad_rho, grad_vel = np.zeros((n, dim)), np.zeros((n, dim, dim))
    fluid.renormalised_gradient(pos, vol, rho, pairs.ptr, pairs.idx, kern.params, np.zeros(n, dtype=np.int8), False,
                                grad_rho)
    riemann.velocity_gradient(pos, vol, vel, pairs, grad_vel)
    out = np.zeros(n), np.zeros(n), np.zeros((n, dim))
    riemann.riemann_ale_rhs(pos, vol, rho, rho * vol, vel, v0, grad_rho, grad_vel, pairs, 10.0, 1.0, tait, mu, morris,
                            np.zeros(dim) if gravity is None else gravity, *out, limited=limited, low_dissipation=low)
    return out


def _eos(tait, c0, rho0):
    """p(rho): Tait with gamma = 7, or linear (psph.schemes.eos)."""
    if tait:
        return lambda r: c0**2 * rho0 / 7.0 * ((r / rho0) ** 7 - 1.0)
    return lambda r: c0**2 * (r - rho0)


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_velocity_gradient_is_exact_for_linear_fields(dim):
    rng, pos, vol, kern, pairs = _setup(dim, dim)
    g = rng.standard_normal((dim, dim))
    vel = pos @ g.T + rng.standard_normal(dim)
    out = np.zeros((len(pos), dim, dim))
    riemann.velocity_gradient(pos, vol, vel, pairs, out)
    assert np.abs(out - g).max() < 1e-10 * np.abs(g).max()


@pytest.mark.parametrize("tait", [False, True])
def test_acoustic_riemann_jump_relations_and_symmetry(tait):
    """Across the left wave p^E - p_L = -z (u^E - u_L), across the right one p^E - p_R = z (u^E - u_R)
    (z = rho_bar c(rho_bar)); p^E = EOS(rho^E); equal states are returned unchanged; swapping the sides and
    reversing the axis gives the same interface state."""
    c0, rho0 = 10.0, 1.0
    eos = _eos(tait, c0, rho0)
    rng = np.random.default_rng(3)
    for _ in range(20):
        rl, rr = 1.0 + 0.03 * rng.standard_normal(2)
        ul, ur = rng.standard_normal(2)
        rho_s, u_s, p_s = riemann.acoustic_riemann(rl, ul, rr, ur, c0, rho0, tait)
        rbar = 0.5 * (rl + rr)
        z = rbar * c0 * ((rbar / rho0) ** 3 if tait else 1.0)
        assert p_s - eos(rl) == pytest.approx(-z * (u_s - ul), rel=1e-12, abs=1e-12)
        assert p_s - eos(rr) == pytest.approx(z * (u_s - ur), rel=1e-12, abs=1e-12)
        assert eos(rho_s) == pytest.approx(p_s, rel=1e-10, abs=1e-10)
        swapped = riemann.acoustic_riemann(rr, -ur, rl, -ul, c0, rho0, tait)
        assert swapped == pytest.approx((rho_s, -u_s, p_s), rel=1e-14, abs=1e-14)
        same = riemann.acoustic_riemann(rl, ul, rl, ul, c0, rho0, tait)
        assert same == pytest.approx((rl, ul, eos(rl)), rel=1e-14, abs=1e-13)


@pytest.mark.parametrize("tait", [False, True])
def test_low_dissipation_pressure(tait):
    """Zhang, Hu and Adams (2017): p^E = (p_L + p_R) / 2 + rho_bar beta (u_L - u_R) / 2 with
    beta = min(3 max(u_L - u_R, 0), c(rho_bar)): the centred pressure where the particles separate, the
    acoustic solver's where they approach faster than c / 3, and in between a dissipation quadratic in the
    approach speed. It is symmetric like the acoustic solver."""
    c0, rho0 = 10.0, 1.0
    eos = _eos(tait, c0, rho0)
    rl, rr = 1.01, 0.995
    centred = 0.5 * (eos(rl) + eos(rr))
    assert riemann.low_dissipation_pressure(rl, -0.2, rr, 0.3, c0, rho0, tait) == pytest.approx(centred, rel=1e-14)
    slow = riemann.low_dissipation_pressure(rl, 0.3, rr, -0.2, c0, rho0, tait)
    assert slow - centred == pytest.approx(0.5 * 1.0025 * 3.0 * 0.5 * 0.5, rel=1e-12)
    _, _, acoustic = riemann.acoustic_riemann(rl, 3.0, rr, -3.0, c0, rho0, tait)
    assert riemann.low_dissipation_pressure(rl, 3.0, rr, -3.0, c0, rho0, tait) == pytest.approx(acoustic, rel=1e-12)
    assert riemann.low_dissipation_pressure(rr, 0.2, rl, -0.3, c0, rho0, tait) == pytest.approx(slow, rel=1e-14)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("tait,low", [(False, False), (True, False), (False, True)])
def test_rhs_conserves_mass_and_momentum(dim, tait, low):
    """The interface state is shared by i and j and the fluxes carry +-grad_i W_ij: sum_i dm_i/dt and
    sum_i d(m v)_i/dt vanish to round-off for any fields (viscosity included); the volume does not (its
    rate is V_i <div v0>_i, not a flux)."""
    rng, pos, vol, kern, pairs = _setup(dim, 10 + dim)
    n = len(pos)
    rho = 1.0 + 0.02 * rng.standard_normal(n)
    vel, v0 = 0.3 * rng.standard_normal((n, dim)), 0.3 * rng.standard_normal((n, dim))  # Mach 0.03
    d_vol, d_mass, d_mom = _rhs(pos, vol, rho, vel, v0, pairs, kern, tait=tait, mu=0.05, morris=dim == 3, low=low)
    assert np.abs(d_mass).max() > 1e-3 and np.abs(d_mom).max() > 1e-3
    assert abs(d_mass.sum()) < 1e-13 * np.abs(d_mass).sum()
    assert np.abs(d_mom.sum(axis=0)).max() < 1e-13 * np.abs(d_mom).sum()
    assert abs(d_vol.sum()) > 1e-3 * np.abs(d_vol).sum()


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("morris", [False, True])
def test_viscosity_and_gravity_are_the_delta_ale_familys(dim, morris):
    """What mu and g add to the momentum rate is delta-ALE's viscous term (seed 001 eq. 11, or Morris') times
    V_i and m_i g, as psph.compute.fluid's brute-force reference sums them: the conservation test, with any
    antisymmetric pair term and no gravity, let a flipped sign, a wrong constant K and V_i g pass (a Riemann
    audit's mutants)."""
    from tests.compute.test_fluid import reference

    rng, pos, vol, kern, pairs = _setup(dim, 30 + dim)
    n = len(pos)
    rho = 1.0 + 0.02 * rng.standard_normal(n)
    vel, v0 = 0.3 * rng.standard_normal((n, dim)), 0.3 * rng.standard_normal((n, dim))
    gravity = np.array([0.3, -1.0, 0.2])[:dim]
    got = _rhs(pos, vol, rho, vel, v0, pairs, kern, mu=0.05, morris=morris, gravity=gravity)[2] \
        - _rhs(pos, vol, rho, vel, v0, pairs, kern, morris=morris)[2]

    def momentum(mu, g):
        return reference(pos, vol, rho, rho * vol, vel, np.zeros((n, dim)), np.zeros(n), kern, c0=10.0, delta=0.0,
                         delta_m=0.0, mu=mu, gravity=g, variant=0, switch=False, kind=np.zeros(n, dtype=np.int8),
                         fluid_only=False, morris=morris)[3]

    want = momentum(0.05, gravity) - momentum(0.0, np.zeros(dim))
    assert np.abs(got - want).max() < 1e-10 * np.abs(want).max()
    viscous = momentum(0.05, np.zeros(dim)) - momentum(0.0, np.zeros(dim))
    assert np.abs(viscous).max() > 0.1 * np.abs(want).max()  # (both terms count)


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("tait", [False, True])
@pytest.mark.parametrize("limited", [True, False])
def test_linear_fields_give_the_centred_fluxes(dim, tait, limited):
    """For linear rho and v, MUSCL puts the same state on both sides of every midpoint (minmod(a, a) = a,
    and without the limiter the gradients are exact), the Riemann solver returns it and the fluxes are the
    centred ones of eq. 5.45 with F_ij = (F_i + F_j)/2 evaluated at the midpoint; with v0 = v
    (Lagrangian) no mass moves between particles at all."""
    rng, pos, vol, kern, pairs = _setup(dim, 20 + dim)
    rho = 1.0 + 0.01 * (pos @ rng.standard_normal(dim))
    g = 0.5 * rng.standard_normal((dim, dim))
    vel = pos @ g.T + rng.standard_normal(dim)
    v0 = vel + pos @ (0.3 * rng.standard_normal((dim, dim))).T
    d_vol, d_mass, d_mom = _rhs(pos, vol, rho, vel, v0, pairs, kern, tait=tait, limited=limited)
    x = pos[:, None, :] - pos[None, :, :]
    r = np.sqrt((x * x).sum(axis=2))
    f = np.where((r > 0.0) & (r < kern.support), kern.radial(r), 0.0)
    w = 2.0 * f[:, :, None] * x * vol[None, :, None]  # 2 grad_i W_ij V_j
    rho_m = 0.5 * (rho[:, None] + rho[None, :])
    v_m = 0.5 * (vel[:, None] + vel[None, :])
    rel = v_m - 0.5 * (v0[:, None] + v0[None, :])
    p_m = 10.0**2 / 7.0 * (rho_m**7 - 1.0) if tait else 10.0**2 * (rho_m - 1.0)
    q = np.einsum("ija,ija->ij", rel, w)
    want_mass = -vol * (rho_m * q).sum(axis=1)
    want_mom = -vol[:, None] * (np.einsum("ij,ija->ia", rho_m * q, v_m) + np.einsum("ij,ija->ia", p_m, w))
    want_vol = vol * np.einsum("ija,ija->i", v0[None, :] - v0[:, None], 0.5 * w)
    assert np.abs(d_mass - want_mass).max() < 1e-10 * np.abs(want_mass).max()
    assert np.abs(d_mom - want_mom).max() < 1e-10 * np.abs(want_mom).max()
    assert np.abs(d_vol - want_vol).max() < 1e-10 * np.abs(want_vol).max()
    _, lagrangian, _ = _rhs(pos, vol, rho, vel, vel, pairs, kern, tait=tait, limited=limited)
    assert np.abs(lagrangian).max() < 1e-12 * np.abs(want_mass).max()


def test_a_jump_is_damped_by_the_riemann_pressure():
    """Two particles approaching each other (u_L - u_R > 0 along their axis) see p^E above the centred
    pressure by z (u_L - u_R) / 2: the solver's dissipation pushes them apart."""
    pos = np.array([[0.0, 0.0], [0.1, 0.0]])
    vol = np.full(2, 0.01)
    from psph.compute.neighbours import build_neighbour_lists
    from psph.compute.smoothing import make_kernel

    kern = make_kernel("wendland_c6", 2, 0.1)
    ptr, idx = build_neighbour_lists(pos, 2, kern.support)
    pairs = fluid.PairCache()
    fluid.renormalised_gradient(pos, vol, np.ones(2), ptr, idx, kern.params, np.zeros(2, dtype=np.int8), False,
                                np.zeros((2, 2)), pairs)
    vel = np.array([[1.0, 0.0], [-1.0, 0.0]])
    _, _, d_mom = _rhs(pos, vol, np.ones(2), vel, vel, pairs, kern)
    assert d_mom[0, 0] < 0.0 < d_mom[1, 0]
    assert d_mom[0, 0] == pytest.approx(-d_mom[1, 0], rel=1e-14)


@pytest.mark.parametrize("low", [False, True])
def test_a_density_jump_between_particles_at_rest_sends_mass_from_the_denser(low):
    """Two particles at rest, rho_i = 1.01 and rho_j = 0.99, constant reconstruction (zero gradients), linear
    equation of state: the solver's interface velocity u^E = (p_i - p_j) / (2 z) along e (from i to j), with
    rho^E = rho0 and p^E = 0, carries dm_i/dt = -V_i V_j rho^E (v^E . 2 f x_ij) = 2 V_i V_j rho^E u^E f r
    out of i and into j (thesis eq. 5.48), whichever pressure (low) the momentum takes."""
    from psph.compute.neighbours import build_neighbour_lists
    from psph.compute.smoothing import kernel_f, make_kernel

    pos = np.array([[0.0, 0.0], [0.1, 0.0]])
    vol, rho, c0 = np.full(2, 0.01), np.array([1.01, 0.99]), 10.0
    kern = make_kernel("wendland_c6", 2, 0.1)
    ptr, idx = build_neighbour_lists(pos, 2, kern.support)
    pairs = fluid.PairCache()
    fluid.renormalised_gradient(pos, vol, rho, ptr, idx, kern.params, np.zeros(2, dtype=np.int8), False,
                                np.zeros((2, 2)), pairs)
    d_vol, d_mass, d_mom = np.zeros(2), np.zeros(2), np.zeros((2, 2))
    still = np.zeros((2, 2))
    riemann.riemann_ale_rhs(pos, vol, rho, rho * vol, still, still, np.zeros((2, 2)), np.zeros((2, 2, 2)), pairs,
                            c0, 1.0, False, 0.0, False, np.zeros(2), d_vol, d_mass, d_mom, low_dissipation=low)
    u_e = (c0**2 * (rho[0] - 1.0) - c0**2 * (rho[1] - 1.0)) / (2.0 * 1.0 * c0)  # z = rho_bar c0 = c0
    expected = 2.0 * vol[0] * vol[1] * 1.0 * u_e * kernel_f(0.1, kern.params) * 0.1
    assert d_mass[0] < 0.0 and d_mass[0] == pytest.approx(expected, rel=1e-12)
    assert d_mass[1] == pytest.approx(-d_mass[0], rel=1e-14) and not d_vol.any()


@pytest.mark.parametrize("tait", [True, False])
def test_particles_separating_faster_than_sound_allows_meet_a_vacuum_not_a_nan(tait):
    """p^E below the equation of state's p(0) (Tait: -c0^2 rho0 / 7) has no density: the solver returns the
    vacuum, p^E = p(0) and rho^E = 0, for states that are valid on their own (the low-dissipation pressure
    has no dissipation where particles separate: the states' mean)."""
    c0 = 1.8
    vacuum = -c0**2 / (7.0 if tait else 1.0)
    rho_s, u_s, p_s = riemann.acoustic_riemann(0.95, -3.0, 0.95, 3.0, c0, 1.0, tait)
    assert (rho_s, u_s) == (0.0, 0.0) and p_s == pytest.approx(vacuum, rel=1e-14)
    p_low = riemann.low_dissipation_pressure(0.95, -3.0, 0.95, 3.0, c0, 1.0, tait)
    assert vacuum < p_low < 0.0
    rho_s, _, p_s = riemann.acoustic_riemann(0.95, -0.01, 0.95, 0.01, c0, 1.0, tait)  # mild: untouched
    assert 0.9 < rho_s < 0.95 and p_s > -c0**2 / 7.0


def test_the_limiter_clips_the_slope_where_the_field_turns():
    """1-D flow v = sin(2 pi x), rho = 1, v0 = 0: dm_i/dt = -V_i <div v>_i -> -V 2 pi cos(2 pi x). Next to
    the peak at x = 1/4 the gradient at i predicts more change over a pair than there is, minmod takes the
    pair's own difference, and the midpoint jump it leaves costs 20-30% of the flux of the two nearest
    particles; unlimited MUSCL keeps them within 2%. Where sin is nearly linear the two agree to 0.1%."""
    n = 200
    pos = ((np.arange(n) + 0.5) / n)[:, None]
    vol = np.full(n, 1.0 / n)
    from psph.compute.neighbours import build_neighbour_lists
    from psph.compute.smoothing import make_kernel

    kern = make_kernel("wendland_c6", 1, 2.0 / n)
    ptr, idx = build_neighbour_lists(pos, n, kern.support)
    pairs = fluid.PairCache()
    fluid.renormalised_gradient(pos, vol, np.ones(n), ptr, idx, kern.params, np.zeros(n, dtype=np.int8), False,
                                np.zeros((n, 1)), pairs)
    vel = np.sin(2.0 * np.pi * pos)
    exact = -vol * 2.0 * np.pi * np.cos(2.0 * np.pi * pos[:, 0])
    rate = {limited: _rhs(pos, vol, np.ones(n), vel, np.zeros_like(vel), pairs, kern, limited=limited)[1]
            for limited in (True, False)}
    nearest = [49, 50]  # x = 0.2475, 0.2525
    assert np.all(np.abs(rate[False][nearest] / exact[nearest] - 1.0) < 0.02)
    assert np.all(np.abs(rate[True][nearest] / exact[nearest] - 1.0) > 0.1)
    smooth = slice(90, 111)  # around x = 1/2
    assert np.abs(rate[True][smooth] / rate[False][smooth] - 1.0).max() < 1e-3
