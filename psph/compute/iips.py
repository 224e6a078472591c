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
scalar unknown of component a of particle p is p * d + a. Several halo images of one particle in a row
(small periodic boxes) add up in one matrix entry.
"""

import numpy as np
from numba import njit

from psph.compute.csr import add_at
from psph.compute.jit import per_dimension
from psph.compute.smoothing import hessian_coefficients, kernel_f
from psph.compute.sums import pair, pair2


@njit(cache=True)
def iips_structure(row, ptr, idx, d):
    """CSR sparsity of the owned free particles' rows, built once per neighbour-list rebuild.

    row: global particle number of every local particle (-1 if fixed); ptr, idx: CSR neighbour lists of
    the owned particles; owned free particles carry consecutive numbers in local order.
    Returns (indptr, indices): scalar CSR with global, sorted, unique columns per row; and slot: for
    each value iips_values produces (its "natural" order: the d diagonal self entries of a particle,
    then d x d entries per free neighbour-list entry), the CSR position it adds into (several halo images
    of one particle in a row share a position). All three are int32, PETSc's index type (a 64-bit-index
    PETSc gets copies): half the memory, and the page faults of fresh memory, of int64. ValueError if a
    position or a column would not fit.
    """
    n_rows = ptr.size - 1
    n_free = 0
    n_values = 0
    for i in range(n_rows):
        if row[i] >= 0:
            n_free += 1
            n_values += d
            for k in range(ptr[i], ptr[i + 1]):
                if row[idx[k]] >= 0:
                    n_values += d * d
    largest = 0
    for i in range(n_rows):
        largest = max(largest, row[i])
    if n_values + n_free * d * (d - 1) >= 2 ** 31 or (largest + 1) * d >= 2 ** 31:
        raise ValueError("the IIPS matrix has more nonzeros on a rank, or more rows, than 32-bit indices allow")
    slot = np.empty(n_values, dtype=np.int32)
    indptr = np.zeros(n_free * d + 1, dtype=np.int32)
    n_entries = n_values // d  # >= the particle entries (self and free neighbours) of all rows
    columns = np.empty(n_entries, dtype=np.int32)  # unique particle columns, row after row
    unique = np.empty(n_entries, dtype=np.int32)  # of each particle entry, its column's place in its row
    width = np.zeros(n_free, dtype=np.int64)
    keys = np.empty(64, dtype=np.int64)
    entry = np.empty(64, dtype=np.int64)
    # unique sorted particle columns of every particle row, by insertion sort of (column, entry) pairs
    # (rows arrive nearly sorted); entry 0 is the particle itself, then its free neighbours in list order
    p = 0
    c = 0
    e = 0
    for i in range(n_rows):
        if row[i] < 0:
            continue
        m = 1 + ptr[i + 1] - ptr[i]
        if m > keys.size:
            keys = np.empty(2 * m, dtype=np.int64)
            entry = np.empty(2 * m, dtype=np.int64)
        keys[0] = row[i]
        entry[0] = 0
        q = 1
        for k in range(ptr[i], ptr[i + 1]):
            v = row[idx[k]]
            if v < 0:
                continue
            t = q
            while t > 0 and keys[t - 1] > v:
                keys[t] = keys[t - 1]
                entry[t] = entry[t - 1]
                t -= 1
            keys[t] = v
            entry[t] = q
            q += 1
        u = -1
        for t in range(q):
            if t == 0 or keys[t] != keys[t - 1]:
                u += 1
                columns[c + u] = keys[t]
            unique[e + entry[t]] = u
        width[p] = u + 1
        c += u + 1
        e += q
        p += 1
    # scalar CSR: particle row p, component a holds columns (col * d + b) for its particle columns
    base = np.zeros(n_free + 1, dtype=np.int64)
    for p in range(n_free):
        base[p + 1] = base[p] + width[p] * d * d
    indices = np.empty(base[n_free], dtype=np.int32)
    start = 0
    for p in range(n_free):
        m = width[p]
        o = base[p]
        for s in range(m):
            col = columns[start + s] * d
            for b in range(d):
                indices[o + s * d + b] = col + b
        for a in range(d):  # the d rows of a particle hold the same columns
            indptr[p * d + a + 1] = o + (a + 1) * m * d
            if a > 0:
                indices[o + a * m * d:o + (a + 1) * m * d] = indices[o:o + m * d]
        start += m
    # natural order -> CSR position: the particle's d diagonal values, then d x d per free neighbour
    v = 0
    e = 0
    p = 0
    for i in range(n_rows):
        if row[i] < 0:
            continue
        m = width[p]
        s = unique[e]
        for a in range(d):
            slot[v] = base[p] + a * m * d + s * d + a
            v += 1
        e += 1
        for k in range(ptr[i], ptr[i + 1]):
            if row[idx[k]] < 0:
                continue
            s = unique[e]
            for a in range(d):
                for b in range(d):
                    slot[v] = base[p] + a * m * d + s * d + b
                    v += 1
            e += 1
        p += 1
    return indptr, indices, slot


@njit(cache=True, inline="always")
def hessian_block(ha, hb, x0, x1, x2, d):
    """The entries of HessW(x) = ha I + hb x x^T on and above its diagonal, row by row (xx, xy, yy in 2-D; xx,
    xy, xz, yy, yz, zz in 3-D): d (d + 1) / 2 of them, the tuple padded with zeros to 6 (the blocks of thesis
    eq. 8.11, 8.32)."""
    if d == 1:
        return (ha + hb * x0 * x0, 0.0, 0.0, 0.0, 0.0, 0.0)
    if d == 2:
        return (ha + hb * x0 * x0, hb * x0 * x1, ha + hb * x1 * x1, 0.0, 0.0, 0.0)
    return (ha + hb * x0 * x0, hb * x0 * x1, hb * x0 * x2, ha + hb * x1 * x1, hb * x1 * x2, ha + hb * x2 * x2)


@njit(cache=True)
def iips_values(pos, vol, row, ptr, idx, kp, where, diag, off):
    """Values of the printed IIPS operator, each added straight into its storage: value number e of the
    natural order (see iips_structure) into diag[where[e]], or off[-1 - where[e]] if where[e] < 0
    (csr.add_at). With where = slot and diag the CSR values this fills the CSR matrix; with PETSc's split
    codes it fills a distributed AIJ matrix's own arrays. diag and off are zeroed first."""
    d = pos.shape[1]
    diag[:] = 0.0
    off[:] = 0.0
    h0 = kernel_f(0.0, kp)  # HessW(0) = W''(0) I = f(0) I
    e = 0
    for i in range(ptr.size - 1):
        if row[i] < 0:
            continue
        for a in range(d):
            add_at(where, e + a, vol[i] * h0, diag, off)
        e += d
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if row[j] < 0:
                continue
            x0, x1, x2, r = pair(pos, i, j, d)
            ha, hb = hessian_coefficients(r, kp)
            h = hessian_block(vol[j] * ha, vol[j] * hb, x0, x1, x2, d)
            # the d x d block row by row, each entry from its place in h (constant indices: a loop indexing the
            # tuple at run time took 1.8-2.3 times as long)
            if d == 1:
                add_at(where, e, h[0], diag, off)
            elif d == 2:
                add_at(where, e, h[0], diag, off)
                add_at(where, e + 1, h[1], diag, off)
                add_at(where, e + 2, h[1], diag, off)
                add_at(where, e + 3, h[2], diag, off)
            else:
                add_at(where, e, h[0], diag, off)
                add_at(where, e + 1, h[1], diag, off)
                add_at(where, e + 2, h[2], diag, off)
                add_at(where, e + 3, h[1], diag, off)
                add_at(where, e + 4, h[3], diag, off)
                add_at(where, e + 5, h[4], diag, off)
                add_at(where, e + 6, h[2], diag, off)
                add_at(where, e + 7, h[4], diag, off)
                add_at(where, e + 8, h[5], diag, off)
            e += d * d


def _compile(d):
    """The matrix-free kernels for dimension d (compute.jit.per_dimension: the product 23% faster in 2-D)."""

    @per_dimension(d)
    def iips_pairs(pos, col, ptr, idx, kp, support, bptr, bcol, hess):
        """See iips_pairs."""
        width = d * (d + 1) // 2
        reach2 = support * support  # Kernel.support: 2h for every kernel (kp[3] is 1/(2h), or 1/h for the cubic)
        m = 0
        bptr[0] = 0
        for i in range(ptr.size - 1):
            p = col[i]
            if p < 0:
                continue
            for k in range(ptr[i], ptr[i + 1]):
                j = idx[k]
                c = col[j]
                if c <= p:  # fixed, or an own block before p (stored in its row)
                    continue
                x0, x1, x2, rr = pair2(pos, i, j, d)
                if rr >= reach2:
                    continue
                ha, hb = hessian_coefficients(np.sqrt(rr), kp)
                block = hessian_block(ha, hb, x0, x1, x2, d)
                bcol[m] = c
                for u in range(width):
                    hess[m, u] = block[u]
                m += 1
            bptr[p + 1] = m

    @per_dimension(d)
    def iips_product(h0, bptr, bcol, hess, z, y):
        """See iips_product."""
        n = bptr.size - 1
        for p in range(n):
            for a in range(d):
                y[p, a] = h0 * z[p, a]
        for p in range(n):
            z0 = z[p, 0]
            z1 = z[p, 1] if d > 1 else 0.0
            z2 = z[p, 2] if d > 2 else 0.0
            y0 = y1 = y2 = 0.0
            for k in range(bptr[p], bptr[p + 1]):
                c = bcol[k]
                if d == 1:
                    y0 += hess[k, 0] * z[c, 0]
                    if c < n:
                        y[c, 0] += hess[k, 0] * z0
                elif d == 2:
                    h00, h01, h11 = hess[k, 0], hess[k, 1], hess[k, 2]
                    y0 += h00 * z[c, 0] + h01 * z[c, 1]
                    y1 += h01 * z[c, 0] + h11 * z[c, 1]
                    if c < n:
                        y[c, 0] += h00 * z0 + h01 * z1
                        y[c, 1] += h01 * z0 + h11 * z1
                else:
                    h00, h01, h02 = hess[k, 0], hess[k, 1], hess[k, 2]
                    h11, h12, h22 = hess[k, 3], hess[k, 4], hess[k, 5]
                    y0 += h00 * z[c, 0] + h01 * z[c, 1] + h02 * z[c, 2]
                    y1 += h01 * z[c, 0] + h11 * z[c, 1] + h12 * z[c, 2]
                    y2 += h02 * z[c, 0] + h12 * z[c, 1] + h22 * z[c, 2]
                    if c < n:
                        y[c, 0] += h00 * z0 + h01 * z1 + h02 * z2
                        y[c, 1] += h01 * z0 + h11 * z1 + h12 * z2
                        y[c, 2] += h02 * z0 + h12 * z1 + h22 * z2
            y[p, 0] += y0
            if d > 1:
                y[p, 1] += y1
            if d > 2:
                y[p, 2] += y2

    return iips_pairs, iips_product


MATRIX_FREE = {d: _compile(d) for d in (1, 2, 3)}


def iips_pairs(pos, col, ptr, idx, kp, support, bptr, bcol, hess):
    """The pairs' Hessian blocks HessW(x_i - x_j), each pair once, for the matrix-free product
    (iips_product). The printed operator is A = H diag(V): H has the blocks HessW(x_i - x_j) off the
    diagonal and HessW(0) = W''(0) I on it, and is symmetric (HessW is even and its blocks symmetric), so
    a pair of the rank's own unknowns is stored once and applied to both rows.

    col: every local particle's unknown block in the rank's local numbering (owned free particles 0..n - 1 in
    local order, other free particles from n on, -1 if fixed). For owned free particle i, of block p =
    col[i]: the free neighbours j closer than `support` (the kernel's radius) with col[j] > p (its own blocks
    after p, and every other rank's: those pairs are applied to row p only, the other rank stores its own
    copy) go to bptr[p]..bptr[p + 1] of bcol (their block) and hess (the d (d + 1) / 2 entries of the
    symmetric block row by row: xx, xy, yy in 2-D). bcol and hess must hold every list entry (the upper
    bound). H's diagonal blocks are W''(0) I (a particle's own periodic images are never its neighbours:
    periodic lengths exceed the support plus skin, schema). The same operator and sums as iips_values;
    pairs beyond the support (a list's skin) are left out."""
    MATRIX_FREE[pos.shape[1]][0](pos, col, ptr, idx, kp, support, bptr, bcol, hess)


def iips_product(h0, bptr, bcol, hess, z, y):
    """y = H z for the symmetric H of iips_pairs (H_pp = h0 I, h0 = W''(0)): with z = V x this is A x, and
    V (H x) is A^T x. z: shape (n + n_ghost, d), the rank's own unknowns then the other ranks' ones that
    columns n.. refer to; y: (n, d). A pair of own blocks (c < n) adds to both rows, one with a ghost block
    to row p only."""
    MATRIX_FREE[z.shape[1]][1](h0, bptr, bcol, hess, z, y)
