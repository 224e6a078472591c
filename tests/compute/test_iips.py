"""The IIPS matrix equals the printed operator of thesis eq. 8.11 / 8.32 built densely from its formula."""

import itertools

import numpy as np
import pytest
from mpi4py import MPI

from psph.compute.iips import iips_structure, iips_values
from psph.particles import Kind
from tests.conftest import periodic_scene


def dense_from_csr(indptr, indices, csr, n):
    """Dense matrix from a CSR pattern and its values."""
    a = np.zeros((n, n))
    for r in range(n):
        a[r, indices[indptr[r]:indptr[r + 1]]] = csr[indptr[r]:indptr[r + 1]]
    return a


def printed_operator(pos, vol, free, kernel, box):
    """A_ii = V_i HessW(0), A_ij = sum over periodic images of V_j HessW(x_i - x_j), free particles only."""
    d = pos.shape[1]
    idx = np.flatnonzero(free)
    n = len(idx)
    images = np.array(list(itertools.product((-1, 0, 1), repeat=d))) * box.length
    a = np.zeros((n * d, n * d))
    for p, i in enumerate(idx):
        a[p * d:(p + 1) * d, p * d:(p + 1) * d] += vol[i] * kernel.hessian(np.zeros((1, d)))[0]
        for q, j in enumerate(idx):
            x = pos[i] - pos[j] + images
            if j == i:
                x = x[np.any(images != 0, axis=1)]
            a[p * d:(p + 1) * d, q * d:(q + 1) * d] += vol[j] * kernel.hessian(x).sum(axis=0)
    return a


@pytest.mark.parametrize("dim,n", [(1, 30), (2, 10), (3, 6)])
def test_matrix_is_the_printed_operator(dim, n):
    from psph.simulation import build_system

    s = build_system(periodic_scene(dim=dim, n=n, sigma=0.2, h_over_dx=1.6), MPI.COMM_SELF)
    p = s.particles
    kinds = p.owned("kind")
    kinds[::7] = Kind.WALL  # fixed particles: neighbours, not unknowns
    s.refresh(["kind"])
    free = kinds == Kind.FLUID
    rows, _, n_free = s.global_rows(free)
    assert n_free == free.sum()
    indptr, indices, slot = iips_structure(rows, s.nbr_ptr, s.nbr_idx, dim)
    values = np.zeros(len(indices))
    iips_values(p["position"], p["volume"], rows, s.nbr_ptr, s.nbr_idx, s.kernel.params, slot, values, np.zeros(0))
    assert len(indptr) == n_free * dim + 1
    for r in range(n_free * dim):  # sorted, unique columns per row (PETSc's CSR preallocation needs it)
        assert np.all(np.diff(indices[indptr[r]:indptr[r + 1]]) > 0)
    got = dense_from_csr(indptr, indices, values, n_free * dim)
    expect = printed_operator(p.owned("position"), p.owned("volume"), free, s.kernel, s.domain)
    assert np.allclose(got, expect, rtol=0, atol=1e-12 * np.abs(expect).max())


def test_a_pattern_beyond_32_bit_indices_is_refused():
    """The pattern is built in int32 (PETSc's index type): a global row number whose scalar columns would
    not fit is an error, not a wrapped index."""
    ptr = np.array([0, 1, 2], dtype=np.int64)
    idx = np.array([1, 0], dtype=np.int64)
    iips_structure(np.array([0, 2 ** 30 - 2], dtype=np.int64), ptr, idx, 2)  # columns up to 2^31 - 3: fits
    with pytest.raises(ValueError, match="32-bit"):
        iips_structure(np.array([0, 2 ** 30], dtype=np.int64), ptr, idx, 2)


def test_printed_operator_differs_from_exact_jacobian():
    """Seeds/README.md: the exact Jacobian of grad C is singular under translation; the printed one is not."""
    from psph.simulation import build_system

    s = build_system(periodic_scene(dim=2, n=8, sigma=0.1), MPI.COMM_SELF)
    pos, vol = s.particles.owned("position"), s.particles.owned("volume")
    free = np.ones(len(pos), bool)
    printed = printed_operator(pos, vol, free, s.kernel, s.domain)
    d, n = 2, len(pos)
    exact = np.zeros_like(printed)  # d grad C_i / d x_j
    for i in range(n):
        for j in range(n):
            if i != j:
                hij = vol[j] * s.kernel.hessian(s.domain.minimum_image(pos[i] - pos[j])[None])[0]
                exact[i * d:(i + 1) * d, j * d:(j + 1) * d] -= hij
                exact[i * d:(i + 1) * d, i * d:(i + 1) * d] += hij
    translation = np.tile([1.0, 0.0], n)
    assert np.abs(exact @ translation).max() < 1e-10 * np.abs(exact).max()
    assert np.abs(printed @ translation).max() > 1e-6 * np.abs(printed).max()
    # off-diagonal blocks: printed = -exact (the printed system is A dx = +grad C)
    off = ~np.kron(np.eye(n, dtype=bool), np.ones((d, d), dtype=bool))
    assert np.allclose(printed[off], -exact[off])


def test_the_printed_operator_breaks_down_at_a_squeezed_pair_and_not_on_the_lattice():
    """psph.studies.iips_pair_defects: on the square lattice Hess C_i, what the printed operator leaves out of
    the Newton Jacobian, is below 0.5% of its self term at h/dx = 3 and grad C vanishes; two particles pushed
    to half a spacing carry the largest Hess C_i (checked by central differences of grad C at the particle),
    and Newton with the printed operator, solved exactly, still reduces h Linf(grad C) a hundredfold."""
    from psph.compute.smoothing import make_kernel
    from psph.studies import iips_pair_defects

    m = 20
    g = (np.arange(m) + 0.5) / m
    lattice, vol = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2), np.full(m * m, 1.0 / m**2)
    even = iips_pair_defects(lattice, vol, 3.0)
    assert even["min_spacing"] == pytest.approx(1.0) and even["hess_c_ratio"].max() < 0.005
    assert max(even["linf"]) < 1e-12

    pair = lattice.copy()
    pair[0, 0] += 0.25 / m
    pair[m, 0] -= 0.25 / m  # its neighbour in x
    r = iips_pair_defects(pair, vol, 3.0)
    assert r["min_spacing"] == pytest.approx(0.5) and r["nearest"][[0, m]] == pytest.approx(0.5)
    assert int(np.argmax(r["hess_c_ratio"])) in (0, m) and r["hess_c_ratio"].max() > 0.2
    assert r["linf"][-1] < r["linf"][0] / 100

    kern = make_kernel("wendland_c6", 2, 3.0 / m)
    images = (pair[None] + np.array(list(itertools.product((-1, 0, 1), repeat=2)), float)[:, None]).reshape(-1, 2)

    def grad_c(x):
        return (np.tile(vol, 9)[:, None] * kern.gradient(x - images)).sum(axis=0)

    eps = 1e-7
    hess = np.stack([(grad_c(pair[0] + eps * e) - grad_c(pair[0] - eps * e)) / (2 * eps) for e in np.eye(2)])
    ratio = np.linalg.norm(hess, 2) / abs(vol[0] * kern.radial(np.zeros(1))[0])
    assert r["hess_c_ratio"][0] == pytest.approx(ratio, rel=1e-5)
