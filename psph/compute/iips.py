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
scalar unknown of component a of particle p is p * d + a. The matrix is given to PETSc as COO triplets;
several halo images of one particle in a row (small periodic boxes) give repeated entries, which add up.
"""

import numpy as np
from numba import njit

from psph.compute.smoothing import hessian_coefficients, kernel_f
from psph.compute.sums import pair


@njit(cache=True)
def iips_pattern(row, ptr, idx, d):
    """COO (rows, cols) of the owned free particles' block rows, built once per neighbour-list rebuild.

    row: global particle number of every local particle (-1 if fixed); ptr, idx: CSR neighbour lists of
    the owned particles. Order: for each owned free particle, its d diagonal self entries, then d x d
    entries per free neighbour-list entry (repeated (row, col) pairs are summed by PETSc).
    """
    n_rows = ptr.size - 1
    nnz = 0
    for i in range(n_rows):
        if row[i] < 0:
            continue
        nnz += d
        for k in range(ptr[i], ptr[i + 1]):
            if row[idx[k]] >= 0:
                nnz += d * d
    rows = np.empty(nnz, dtype=np.int64)
    cols = np.empty(nnz, dtype=np.int64)
    e = 0
    for i in range(n_rows):
        ri = row[i]
        if ri < 0:
            continue
        for a in range(d):
            rows[e] = ri * d + a
            cols[e] = ri * d + a
            e += 1
        for k in range(ptr[i], ptr[i + 1]):
            rj = row[idx[k]]
            if rj < 0:
                continue
            for a in range(d):
                for b in range(d):
                    rows[e] = ri * d + a
                    cols[e] = rj * d + b
                    e += 1
    return rows, cols


@njit(cache=True)
def iips_values(pos, vol, row, ptr, idx, kp, values):
    """COO values of the printed IIPS operator, in the order of iips_pattern."""
    d = pos.shape[1]
    h0 = kernel_f(0.0, kp)  # HessW(0) = W''(0) I = f(0) I
    e = 0
    for i in range(ptr.size - 1):
        if row[i] < 0:
            continue
        values[e:e + d] = vol[i] * h0
        e += d
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if row[j] < 0:
                continue
            x0, x1, x2, r = pair(pos, i, j, d)
            ha, hb = hessian_coefficients(r, kp)
            ha *= vol[j]
            hb *= vol[j]
            if d == 2:
                values[e] = ha + hb * x0 * x0
                values[e + 1] = hb * x0 * x1
                values[e + 2] = values[e + 1]
                values[e + 3] = ha + hb * x1 * x1
            elif d == 3:
                xs = (x0, x1, x2)
                for a in range(3):
                    for b in range(3):
                        values[e + 3 * a + b] = hb * xs[a] * xs[b] + (ha if a == b else 0.0)
            else:
                values[e] = ha + hb * x0 * x0
            e += d * d
