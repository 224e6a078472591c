"""The explicit shifting kernels against brute-force numpy sums of their formulas (thesis eq. 6.15 and
6.33-6.34) over all pairs of a perturbed lattice: the kernels are specialised per dimension and skip the
lists' skin without a branch."""

import numpy as np
import pytest

from psph.compute import shift_velocity
from tests.helpers import perturbed_lattice


def cloud(dim, seed):
    rng = np.random.default_rng(seed)
    n_side = {1: 40, 2: 9, 3: 5}[dim]
    dx = 1.0 / n_side
    pos, vol, kern, ptr, idx = perturbed_lattice(rng, dim, n_side)
    x = pos[:, None, :] - pos[None, :, :]
    r = np.sqrt((x * x).sum(axis=2))
    use = (r > 0.0) & (r < kern.support)
    return rng, dx, pos, vol, kern, ptr, idx, x, r, use


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_corrected_grad_c_matches_brute_force(dim):
    _, dx, pos, vol, kern, ptr, idx, x, r, use = cloud(dim, dim)
    w_ref = float(kern.value(np.array([dx]))[0])
    weight = np.where(use, kern.radial(r) * (1.0 + 0.2 * (kern.value(r) / w_ref) ** 4), 0.0) * vol[None, :]
    want = np.einsum("ij,ija->ia", weight, x)
    got = np.zeros_like(pos)
    shift_velocity.corrected_grad_c(pos, vol, ptr, idx, kern.params, 0.2, 4.0, w_ref, got)
    assert np.abs(got - want).max() < 1e-10 * np.abs(want).max()


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_neuhauser_acceleration_matches_brute_force(dim):
    rng, dx, pos, vol, kern, ptr, idx, x, r, use = cloud(dim, 10 + dim)
    v0 = rng.standard_normal(pos.shape)
    pref = 1.0 + rng.random(len(pos))
    c0, alpha = 10.0, 0.1
    dv = v0[:, None, :] - v0[None, :, :]
    safe_r = np.where(use, r, 1.0)
    approach = -np.einsum("ija,ija->ij", dv, x) / safe_r
    s = np.where(use, (0.5 * (pref[:, None] + pref[None, :]) + 0.5 * c0 * approach) * kern.radial(r), 0.0)
    smooth = np.where(use, alpha * c0 / kern.h * kern.value(r), 0.0)
    want = -np.einsum("ij,ija->ia", s * vol[None, :], x) - np.einsum("ij,ija->ia", smooth * vol[None, :], dv)
    got = np.zeros_like(pos)
    shift_velocity.neuhauser_acceleration(pos, vol, v0, pref, ptr, idx, kern.params, c0, alpha, got)
    assert np.abs(got - want).max() < 1e-10 * np.abs(want).max()


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_neuhauser_pushes_a_pair_apart_and_harder_as_it_closes(dim):
    """The sign the brute-force test above cannot check (it sums the same reading): thesis eq. 6.33 / 7.1,
    read with its own grad_i W_ij (eq. 5.48), would pull particles together and eq. 7.4 is printed with the
    opposite sign; psph takes the repulsive reading. Two particles 0.8 dx apart along x, at rest, push each
    other apart; approaching each other (the upwind term c0/2 (v0_i - v0_j) . e_ij), harder; receding,
    less."""
    from psph.compute.smoothing import make_kernel

    dx = 0.1
    kern = make_kernel("wendland_c6", dim, 2.0 * dx)
    pos = np.zeros((2, dim))
    pos[1, 0] = 0.8 * dx
    vol, pref = np.full(2, dx**dim), np.ones(2)
    ptr, idx = np.array([0, 1, 2]), np.array([1, 0])

    def push(speed):  # particle 0's acceleration along x; the pair closes at 2 * speed
        v0 = np.zeros((2, dim))
        v0[0, 0], v0[1, 0] = speed, -speed
        out = np.zeros((2, dim))
        shift_velocity.neuhauser_acceleration(pos, vol, v0, pref, ptr, idx, kern.params, 10.0, 0.0, out)
        assert np.allclose(out[0], -out[1]) and np.allclose(out[:, 1:], 0.0)
        return out[0, 0]

    assert push(0.0) < 0.0  # away from particle 1, on its right
    assert push(0.01) < push(0.0) < push(-0.01) < 0.0


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("fluid_only", [False, True])
def test_grad_c_from_the_gradient_pass_is_the_same(dim, fluid_only):
    """compute.fluid.renormalised_gradient with grad_c: the corrected grad C over every neighbour, the
    renormalised gradient and the pair cache over the fluid ones (fluid_only), bit for bit as the two
    kernels apart; with fluid_only, rows of solids keep their gradient untouched and get a zero grad C."""
    from psph.compute import fluid

    rng, dx, pos, vol, kern, ptr, idx, *_ = cloud(dim, 10 + dim)
    kind = np.where(rng.random(len(pos)) < 0.3, 1, 0).astype(np.int8)
    phi = rng.random(len(pos))
    w_ref = float(kern.value(np.array([dx]))[0])
    apart, fused = np.full_like(pos, 7.0), np.full_like(pos, 7.0)
    pairs_apart, pairs_fused = fluid.PairCache(), fluid.PairCache()
    fluid.renormalised_gradient(pos, vol, phi, ptr, idx, kern.params, kind, fluid_only, apart, pairs_apart)
    grad_apart, grad_fused = np.zeros_like(pos), np.zeros_like(pos)
    shift_velocity.corrected_grad_c(pos, vol, ptr, idx, kern.params, 0.2, 4.0, w_ref, grad_apart)
    fluid.renormalised_gradient(pos, vol, phi, ptr, idx, kern.params, kind, fluid_only, fused, pairs_fused,
                                grad_c=(0.2, 4.0, w_ref, grad_fused))
    moved = (kind == 0) | (not fluid_only)  # with fluid_only a solid's row is skipped, its grad C zero
    assert np.array_equal(apart, fused) and np.array_equal(grad_apart[moved], grad_fused[moved])
    assert (grad_fused[~moved] == 0.0).all()
    assert np.array_equal(pairs_apart.ptr, pairs_fused.ptr)
    n = pairs_apart.ptr[-1]
    assert np.array_equal(pairs_apart.idx[:n], pairs_fused.idx[:n]) and np.array_equal(pairs_apart.f[:n],
                                                                                      pairs_fused.f[:n])
    if fluid_only:
        assert (fused[kind != 0] == 7.0).all() and (fused[kind == 0] != 7.0).all()
