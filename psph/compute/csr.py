"""Scattering values into CSR storage, including PETSc's split (diagonal / off-diagonal) AIJ layout (numba)."""

import numpy as np
from numba import njit


@njit(cache=True)
def block_positions(indptr, indices, col_start, col_end, d_start, o_start, block, where):
    """For each CSR position (global, sorted columns): its block (0 diagonal: col_start <= col < col_end,
    1 off-diagonal) and its position in that block's values, rows starting at d_start[r] / o_start[r]
    (within a row PETSc keeps both blocks' columns sorted, so positions follow from counting). Returns
    False if the rows' lengths disagree with d_start / o_start."""
    for r in range(indptr.size - 1):
        pd = d_start[r]
        po = o_start[r]
        for k in range(indptr[r], indptr[r + 1]):
            if col_start <= indices[k] < col_end:
                block[k] = 0
                where[k] = pd
                pd += 1
            else:
                block[k] = 1
                where[k] = po
                po += 1
        if pd != d_start[r + 1] or po != o_start[r + 1]:
            return False
    return True


@njit(cache=True)
def split_csr(indptr, indices, col_start, col_end):
    """Split a CSR (global, sorted columns) into PETSc's MPIAIJ blocks: the diagonal block's row pointers
    and local columns (col - col_start), and the off-diagonal block's row pointers and global columns."""
    n = indptr.size - 1
    di = np.zeros(n + 1, dtype=np.int64)
    oi = np.zeros(n + 1, dtype=np.int64)
    for r in range(n):
        inside = 0
        for k in range(indptr[r], indptr[r + 1]):
            if col_start <= indices[k] < col_end:
                inside += 1
        di[r + 1] = di[r] + inside
        oi[r + 1] = oi[r] + indptr[r + 1] - indptr[r] - inside
    block = np.empty(indices.size, dtype=np.int8)
    where = np.empty(indices.size, dtype=np.int64)
    block_positions(indptr, indices, col_start, col_end, di, oi, block, where)
    dj = np.empty(di[n], dtype=np.int64)
    oj = np.empty(oi[n], dtype=np.int64)
    for k in range(indices.size):
        if block[k] == 0:
            dj[where[k]] = indices[k] - col_start
        else:
            oj[where[k]] = indices[k]
    return di, dj, oi, oj


@njit(cache=True)
def split_positions(indptr, indices, col_start, col_end, ia_d, ia_o, slot, target, offset):
    """For each natural value (via slot -> CSR position): block (0 diagonal, 1 off-diagonal) and position
    in the blocks whose row pointers PETSc reports (ia_d, ia_o). Returns False if they disagree with the
    CSR (then the caller uses the generic path)."""
    block = np.empty(indices.size, dtype=np.int8)
    where = np.empty(indices.size, dtype=np.int64)
    if not block_positions(indptr, indices, col_start, col_end, ia_d, ia_o, block, where):
        return False
    for e in range(slot.size):
        target[e] = block[slot[e]]
        offset[e] = where[slot[e]]
    return True


@njit(cache=True)
def write_split(values, target, offset, diag, off):
    diag[:] = 0.0
    off[:] = 0.0
    for e in range(values.size):
        if target[e] == 0:
            diag[offset[e]] += values[e]
        else:
            off[offset[e]] += values[e]


@njit(cache=True)
def scatter(values, slot, out):
    out[:] = 0.0
    for e in range(values.size):
        out[slot[e]] += values[e]


@njit(cache=True)
def block_major_positions(indptr, d):
    """Map the positions of a scalar CSR whose block rows (d scalar rows each) hold d x d blocks in
    row-oriented layout (row a of the block row, then block s, then column b) to the block-contiguous
    layout of BAIJ values (block s, then a, then b)."""
    out = np.empty(indptr[-1], dtype=np.int64)
    for p in range((indptr.size - 1) // d):
        base = indptr[p * d]
        m = (indptr[p * d + 1] - base) // d
        for a in range(d):
            for s in range(m):
                for b in range(d):
                    out[base + a * m * d + s * d + b] = base + s * d * d + a * d + b
    return out
