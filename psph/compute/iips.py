"""The IIPS linear system in CSR form (numba; no PETSc, no communication).

Implicit iterative particle shifting (thesis 000, chapter 8) solves, at every Newton iteration,

    A dx = grad C,     x <- x + dx,

with one d x d block row per free particle i (thesis eq. 8.11 in 1-D, 8.32 in 2-D, the same in 3-D):

    A_ii = V_i HessW(0)               (the printed self term, j = i)
    A_ij = V_j HessW(x_i - x_j)       (each free neighbour j)

as read in seeds/README.md: this is the printed operator, not the exact Newton Jacobian of grad C (whose
diagonal block is sum_k V_k HessW(x_i - x_k)); the exact Jacobian is singular under uniform translation
and the iteration built on it diverges from perturbed lattices, while this one converges (tests and
run_scripts/iips_static.py measure it). Fixed particles (walls, free surface, inflow/outflow: row < 0)
are not unknowns but still contribute to grad C (thesis section 10.2.1).

Rows are numbered per particle (`row`, global, from an exclusive scan; -1 for fixed particles) and the
scalar unknown of component a of particle p is p * d + a. Several halo images of one particle may sit in
a row (small periodic boxes): their blocks add up in one column slot.
"""

import numpy as np
from numba import njit

from psph.compute.smoothing import hessian_coefficients, kernel_f


@njit(cache=True)
def iips_structure(row, ptr, idx, d):
    """Sparsity of the owned free rows, built once per neighbour-list rebuild.

    row: global particle number of every local particle (-1 if fixed); ptr, idx: CSR neighbour lists of
    the owned particles. Owned free particles must carry consecutive numbers in local order.
    Returns (indptr, indices) of the scalar CSR matrix (global columns, sorted within rows), and for the
    value kernel: self_slot (slot of the diagonal block in each particle row), pair_slot (slot of every
    neighbour-list entry, -1 if the neighbour is fixed or the row is) and block_start (first value of each
    particle row's block).
    """
    n_rows = ptr.size - 1
    n_free = 0
    for i in range(n_rows):
        if row[i] >= 0:
            n_free += 1
    counts = np.zeros(n_free, dtype=np.int64)
    pair_slot = np.full(idx.size, -1, dtype=np.int64)
    self_slot = np.zeros(n_free, dtype=np.int64)
    # first pass: unique sorted neighbour columns per particle row
    cols_per_row = []
    p = 0
    for i in range(n_rows):
        if row[i] < 0:
            continue
        m = 1
        for k in range(ptr[i], ptr[i + 1]):
            if row[idx[k]] >= 0:
                m += 1
        cand = np.empty(m, dtype=np.int64)
        cand[0] = row[i]
        c = 1
        for k in range(ptr[i], ptr[i + 1]):
            if row[idx[k]] >= 0:
                cand[c] = row[idx[k]]
                c += 1
        uniq = np.unique(cand)
        counts[p] = uniq.size
        self_slot[p] = np.searchsorted(uniq, row[i])
        for k in range(ptr[i], ptr[i + 1]):
            if row[idx[k]] >= 0:
                pair_slot[k] = np.searchsorted(uniq, row[idx[k]])
        cols_per_row.append(uniq)
        p += 1
    block_start = np.zeros(n_free + 1, dtype=np.int64)
    for p in range(n_free):
        block_start[p + 1] = block_start[p] + counts[p] * d * d
    indptr = np.zeros(n_free * d + 1, dtype=np.int64)
    indices = np.empty(block_start[n_free], dtype=np.int64)
    for p in range(n_free):
        uniq = cols_per_row[p]
        m = uniq.size
        for a in range(d):
            r = p * d + a
            start = block_start[p] + a * m * d
            indptr[r + 1] = start + m * d
            for s in range(m):
                for b in range(d):
                    indices[start + s * d + b] = uniq[s] * d + b
    return indptr, indices, self_slot, pair_slot, block_start


@njit(cache=True)
def iips_values(pos, vol, row, ptr, idx, kp, self_slot, pair_slot, block_start, values):
    """Fill the CSR values of the printed IIPS operator (layout of iips_structure)."""
    d = pos.shape[1]
    values[:] = 0.0
    h0 = kernel_f(0.0, kp)  # HessW(0) = W''(0) I = f(0) I
    p = 0
    for i in range(ptr.size - 1):
        if row[i] < 0:
            continue
        base = block_start[p]
        m = (block_start[p + 1] - base) // (d * d)
        s = self_slot[p]
        for a in range(d):
            values[base + a * m * d + s * d + a] += vol[i] * h0
        for k in range(ptr[i], ptr[i + 1]):
            s = pair_slot[k]
            if s < 0:
                continue
            j = idx[k]
            r2 = 0.0
            for a in range(d):
                t = pos[i, a] - pos[j, a]
                r2 += t * t
            ha, hb = hessian_coefficients(np.sqrt(r2), kp)
            for a in range(d):
                xa = pos[i, a] - pos[j, a]
                for b in range(d):
                    xb = pos[i, b] - pos[j, b]
                    v = hb * xa * xb
                    if a == b:
                        v += ha
                    values[base + a * m * d + s * d + b] += vol[j] * v
        p += 1
