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
