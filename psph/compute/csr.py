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
    and local columns (col - col_start), and the off-diagonal block's row pointers and global columns, as
    int32 (PETSc's index type; the caller has checked that the pattern fits)."""
    n = indptr.size - 1
    di = np.zeros(n + 1, dtype=np.int32)
    oi = np.zeros(n + 1, dtype=np.int32)
    for r in range(n):
        inside = 0
        for k in range(indptr[r], indptr[r + 1]):
            if col_start <= indices[k] < col_end:
                inside += 1
        di[r + 1] = di[r] + inside
        oi[r + 1] = oi[r] + indptr[r + 1] - indptr[r] - inside
    block = np.empty(indices.size, dtype=np.int8)
    where = np.empty(indices.size, dtype=np.int32)  # positions within a block, which fit (see split_positions)
    block_positions(indptr, indices, col_start, col_end, di, oi, block, where)
    dj = np.empty(di[n], dtype=np.int32)
    oj = np.empty(oi[n], dtype=np.int32)
    for k in range(indices.size):
        if block[k] == 0:
            dj[where[k]] = indices[k] - col_start
        else:
            oj[where[k]] = indices[k]
    return di, dj, oi, oj


@njit(cache=True)
def split_positions(indptr, indices, col_start, col_end, ia_d, ia_o, slot, where):
    """For each natural value (via slot -> CSR position): its position in the blocks whose row pointers
    PETSc reports (ia_d, ia_o), coded as `add_at` reads it (p: diagonal block, -1 - p: off-diagonal block).
    Returns False if they disagree with the CSR (then the caller uses the generic path)."""
    block = np.empty(indices.size, dtype=np.int8)
    # int32, as the codes: the caller's pattern has fewer than 2^31 values (compute.iips.iips_structure checks),
    # and int64 here made the largest transient of a distributed matrix's build (25 bytes per nonzero at the peak)
    position = np.empty(indices.size, dtype=np.int32)
    if not block_positions(indptr, indices, col_start, col_end, ia_d, ia_o, block, position):
        return False
    for e in range(slot.size):
        k = slot[e]
        where[e] = position[k] if block[k] == 0 else -1 - position[k]
    return True


@njit(cache=True)
def add_at(where, e, value, diag, off):
    """Add value number e into its storage: diag[where[e]] if where[e] >= 0, else off[-1 - where[e]] (the
    off-diagonal block of a distributed AIJ matrix; unused, and may be empty, when every code is >= 0)."""
    w = where[e]
    if w >= 0:
        diag[w] += value
    else:
        off[-1 - w] += value


@njit(cache=True)
def block_pattern(indptr, indices, d):
    """The block CSR (block row pointers, block columns; int32) of a scalar CSR whose d scalar rows per
    block row hold d x d blocks in row-oriented layout (row a of the block row, then block s, then b)."""
    n = (indptr.size - 1) // d
    bptr = np.zeros(n + 1, dtype=np.int32)
    for p in range(n):
        bptr[p + 1] = bptr[p] + (indptr[p * d + 1] - indptr[p * d]) // d
    bcols = np.empty(bptr[n], dtype=np.int32)
    for p in range(n):
        for s in range(bptr[p + 1] - bptr[p]):
            bcols[bptr[p] + s] = indices[indptr[p * d] + s * d] // d
    return bptr, bcols


@njit(cache=True)
def block_codes(indptr, d, bptr, block_where, slot, where):
    """Position codes (as add_at reads them) of the natural values of a blocked matrix: scalar CSR
    position slot[e] lies in block k of the block CSR (bptr) at row a, column b; block_where[k] codes the
    block's position in PETSc's diagonal (>= 0) or off-diagonal (< 0) block storage, where each d x d
    block is stored column-major (BAIJ), so the value goes to d * d * position + b * d + a."""
    code = np.empty(indptr[-1], dtype=np.int32)
    d2 = d * d
    for p in range(bptr.size - 1):
        m = bptr[p + 1] - bptr[p]
        for a in range(d):
            for s in range(m):
                w = block_where[bptr[p] + s]
                for b in range(d):
                    inner = b * d + a
                    code[indptr[p * d + a] + s * d + b] = w * d2 + inner if w >= 0 else -1 - ((-1 - w) * d2 + inner)
    for e in range(slot.size):
        where[e] = code[slot[e]]
