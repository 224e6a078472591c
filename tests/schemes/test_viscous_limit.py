"""The viscous time-step limit (psph.schemes.viscous_limit): its constants, its lattice eigenvalue against the
assembled operator, its estimate on disordered particles, and a flow it keeps stable."""

import json

import numpy as np
import pytest

from psph.compute import sums
from psph.compute.neighbours import build_neighbour_lists
from psph.compute.smoothing import make_kernel
from psph.schemes.viscous_limit import REAL_AXIS_REACH, SAFETY, lattice_symbol
from tests.helpers import CASES, run_psph


@pytest.mark.parametrize("integrator,order", [("rk3", 3), ("rk4", 4)])
def test_the_reach_is_where_the_stability_polynomial_leaves_the_unit_disc(integrator, order):
    """R(z) = sum_{k <= s} z^k / k! for an s-stage RK of order s: |R| <= 1 on [-reach, 0] and not beyond."""
    def r(z):
        return sum(z ** k / np.prod(np.arange(1, k + 1)) for k in range(order + 1))

    reach = REAL_AXIS_REACH[integrator]
    inside = np.linspace(-reach, 0.0, 20001)
    assert np.abs(r(inside)).max() <= 1.0 + 1e-12
    assert abs(abs(r(-reach)) - 1.0) < 1e-12 and abs(r(-reach * (1.0 + 1e-6))) > 1.0


def periodic_operator(n, dim, h_over_dx, morris, sigma, rng):
    """The viscous operator (per unit nu) of psph's sums on a periodic lattice of n^dim particles perturbed by
    sigma dx, as a dense matrix, with the lattice's spacing, kernel and max_i sum_j V_j F_ij."""
    dx = 1.0 / n
    grid = np.stack(np.meshgrid(*[np.arange(n) * dx + 0.5 * dx] * dim, indexing="ij"), axis=-1).reshape(-1, dim)
    grid = (grid + sigma * dx * rng.standard_normal(grid.shape)) % 1.0
    kernel = make_kernel("wendland_c6", dim, h_over_dx * dx)
    shifts = np.stack(np.meshgrid(*[[-1.0, 0.0, 1.0]] * dim, indexing="ij"), axis=-1).reshape(-1, dim)
    shifts = shifts[np.argsort(np.abs(shifts).sum(axis=1), kind="stable")]  # the unshifted copy first
    pos = np.ascontiguousarray(np.concatenate([grid + s for s in shifts]))
    m = len(grid)
    ptr, idx = build_neighbour_lists(pos, m, kernel.support)
    vol = np.full(len(pos), dx ** dim)
    matrix = np.zeros((m * dim, m * dim))
    for column in range(m * dim):
        u = np.zeros((m, dim))
        u.flat[column] = 1.0
        images = np.tile(u, (len(shifts), 1))
        out = np.zeros((m, dim))
        if morris:
            for a in range(dim):
                sums.laplacian_morris(pos, vol, ptr, idx, kernel.params, np.ascontiguousarray(images[:, a]), out[:, a])
        else:
            sums.viscous_pi(pos, vol, ptr, idx, kernel.params, images, out)
        matrix[:, column] = out.ravel()
    diagonal = sums.largest_kernel_factor_sum(pos, vol, ptr, idx, kernel.params)
    return matrix, dx, kernel, diagonal


@pytest.mark.parametrize("morris", [False, True])
@pytest.mark.parametrize("h_over_dx", [1.5, 2.0])
def test_the_lattice_symbol_is_the_assembled_operators_largest_eigenvalue(morris, h_over_dx):
    """On a periodic lattice the operator is a convolution: its eigenvalues are its symbol's values (pi_ij with
    Wendland C6 at h/dx = 2: lambda_max h^2 = 30.17, against 0.125 h^2 / nu x 2.51 = 20.1 that RK3 tolerated
    under the old limit)."""
    matrix, dx, kernel, diagonal = periodic_operator(12, 2, h_over_dx, morris, 0.0, np.random.default_rng(0))
    eigenvalues = np.linalg.eigvals(matrix)
    largest, lattice_diagonal = lattice_symbol(kernel, 2, dx, morris)
    assert np.abs(eigenvalues.imag).max() < 1e-9 * largest and eigenvalues.real.max() < 1e-9 * largest
    assert np.isclose(-eigenvalues.real.min(), largest, rtol=1e-9)
    assert np.isclose(diagonal, lattice_diagonal, rtol=1e-12)
    if not morris and h_over_dx == 2.0:
        assert np.isclose(largest * kernel.h ** 2, 30.17, atol=0.01)


@pytest.mark.parametrize("morris", [False, True])
@pytest.mark.parametrize("dim,n,sigma", [(2, 12, 0.25), (2, 12, 0.5), (2, 12, 0.8), (3, 5, 0.3)])
def test_the_estimate_on_disordered_particles_keeps_the_step_stable(morris, dim, n, sigma):
    """Disorder widens the spectrum (by up to 1.85 times here); the lattice's eigenvalue scaled by the largest
    diagonal sum stays above SAFETY times the true one, so SAFETY x reach / (nu estimate) is a stable step."""
    rng = np.random.default_rng(5)
    for _ in range(2):
        matrix, dx, kernel, diagonal = periodic_operator(n, dim, 2.0, morris, sigma, rng)
        true = -np.linalg.eigvals(matrix).real.min()
        largest, lattice_diagonal = lattice_symbol(kernel, dim, dx, morris)
        estimate = largest * max(1.0, diagonal / lattice_diagonal)
        assert SAFETY * true < estimate < 1.5 * true


def test_a_viscous_taylor_green_runs_stably_at_the_limit(tmp_path):
    """Re = 0.01 (nu = 100): the step is the viscous limit's, 0.0666 h^2 / nu on the lattice. With the old
    0.125 h^2 / nu the run blew up within its first steps; now the velocity decays as the analytic one does."""
    res = run_psph("run", CASES / "taylor_green.toml", "--out", tmp_path, "--quiet", "--set", "domain.dx=0.05",
                   "--set", "physics.reynolds=0.01", "--set", "shifting.method=none", "--set", "iips.update=none",
                   "--set", "time.t_end=2e-4")
    assert res.returncode == 0, res.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert 30 <= summary["steps"] <= 33  # 2e-4 / 6.66e-6 = 30.0: the viscous limit sets the step
    assert summary["final"]["L2_vx_error"] < 0.02
