"""Cell-linked-list neighbour search producing CSR neighbour lists (numba).

The search runs over all local particles (owned + halo) and builds rows for the first `n_rows` particles
(the owned ones). Row i lists every local j != i with |x_i - x_j| < radius, coincident particles
included. The list radius is the kernel support plus a skin, so a list stays valid while no particle has
moved more than half the skin (Verlet list); pairs beyond the support contribute zero in every sum.
"""

import numpy as np
from numba import njit

# Cap on the number of cells relative to the particle count: sparse clouds get coarser cells.
_MAX_CELLS_PER_PARTICLE = 4


@njit(cache=True)
def _cell_grid(pos, radius):
    n, d = pos.shape
    lo = np.zeros(3)
    ncell = np.ones(3, dtype=np.int64)
    size = radius
    if n == 0:
        return lo, ncell, size
    hi = np.zeros(3)
    for a in range(d):
        lo[a] = pos[0, a]
        hi[a] = pos[0, a]
    for i in range(n):
        for a in range(d):
            v = pos[i, a]
            if v < lo[a]:
                lo[a] = v
            if v > hi[a]:
                hi[a] = v
    limit = _MAX_CELLS_PER_PARTICLE * n + 64
    while True:
        total = 1
        for a in range(d):
            ncell[a] = int((hi[a] - lo[a]) / size) + 1
            total *= ncell[a]
        if total <= limit:
            break
        size *= 1.5
    return lo, ncell, size


@njit(cache=True)
def _cell_index(pos, lo, ncell, size):
    n, d = pos.shape
    cell = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = 0
        for a in range(d):
            k = int((pos[i, a] - lo[a]) / size)
            if k >= ncell[a]:
                k = ncell[a] - 1
            c = c * ncell[a] + k
        cell[i] = c
    return cell


@njit(cache=True)
def _bin(cell, ntotal):
    start = np.zeros(ntotal + 1, dtype=np.int64)
    for i in range(cell.size):
        start[cell[i] + 1] += 1
    for c in range(ntotal):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    members = np.empty(cell.size, dtype=np.int64)
    for i in range(cell.size):
        members[fill[cell[i]]] = i
        fill[cell[i]] += 1
    return start, members


@njit(cache=True)
def _scan(pos, n_rows, radius, lo, ncell, size, cell, start, members, ptr, idx, fill):
    """Count (fill=False) or write (fill=True) the neighbours of rows 0..n_rows-1."""
    d = pos.shape[1]
    r2max = radius * radius
    nx = ncell[0]
    ny = ncell[1] if d > 1 else 1
    nz = ncell[2] if d > 2 else 1
    for i in range(n_rows):
        c = cell[i]
        # unravel the cell index (row-major over the d used axes)
        if d == 1:
            cx, cy, cz = c, 0, 0
        elif d == 2:
            cx, cy, cz = c // ny, c % ny, 0
        else:
            cx, cy, cz = c // (ny * nz), (c // nz) % ny, c % nz
        count = 0
        pos_out = ptr[i]
        for ax in range(max(cx - 1, 0), min(cx + 2, nx)):
            for ay in range(max(cy - 1, 0), min(cy + 2, ny)):
                for az in range(max(cz - 1, 0), min(cz + 2, nz)):
                    cc = (ax * ny + ay) * nz + az
                    for m in range(start[cc], start[cc + 1]):
                        j = members[m]
                        if j == i:
                            continue
                        r2 = 0.0
                        for a in range(d):
                            t = pos[i, a] - pos[j, a]
                            r2 += t * t
                        if r2 < r2max:
                            if fill:
                                idx[pos_out + count] = j
                            count += 1
        if not fill:
            ptr[i + 1] = count


@njit(cache=True)
def build_neighbour_lists(pos, n_rows, radius):
    """CSR neighbour lists (ptr, idx) of rows 0..n_rows-1 over all particles in `pos`.

    pos: (n, d) positions of owned then halo particles; radius: list radius (support + skin).
    Returns ptr (n_rows + 1,) and idx (ptr[-1],) int64; row i is idx[ptr[i]:ptr[i+1]], ascending in
    cell order, j != i.
    """
    lo, ncell, size = _cell_grid(pos, radius)
    d = pos.shape[1]
    total = 1
    for a in range(d):
        total *= ncell[a]
    cell = _cell_index(pos, lo, ncell, size)
    start, members = _bin(cell, total)
    ptr = np.zeros(n_rows + 1, dtype=np.int64)
    idx = np.empty(0, dtype=np.int64)
    _scan(pos, n_rows, radius, lo, ncell, size, cell, start, members, ptr, idx, False)
    for i in range(n_rows):
        ptr[i + 1] += ptr[i]
    idx = np.empty(ptr[n_rows], dtype=np.int64)
    _scan(pos, n_rows, radius, lo, ncell, size, cell, start, members, ptr, idx, True)
    return ptr, idx


@njit(cache=True)
def spatial_order(pos, cell_size):
    """Permutation that sorts particles cell by cell (row-major cells of side `cell_size`).

    Applied to owned particles after each neighbour-list rebuild so that neighbours sit close in memory.
    """
    lo, ncell, size = _cell_grid(pos, cell_size)
    cell = _cell_index(pos, lo, ncell, size)
    return np.argsort(cell, kind="mergesort")


@njit(cache=True)
def max_displacement(pos, ref, n):
    """max_i |pos_i - ref_i| over the first n particles."""
    d = pos.shape[1]
    m = 0.0
    for i in range(n):
        r2 = 0.0
        for a in range(d):
            t = pos[i, a] - ref[i, a]
            r2 += t * t
        if r2 > m:
            m = r2
    return np.sqrt(m)


@njit(cache=True)
def coincident_rows(pos, gid, ptr, idx, tol):
    """Owned rows i with a neighbour j closer than `tol` and gid_j < gid_i (one of each close pair)."""
    d = pos.shape[1]
    out = np.zeros(ptr.size - 1, dtype=np.bool_)
    for i in range(ptr.size - 1):
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if gid[j] >= gid[i]:
                continue
            r2 = 0.0
            for a in range(d):
                t = pos[i, a] - pos[j, a]
                r2 += t * t
            if r2 < tol * tol:
                out[i] = True
                break
    return np.flatnonzero(out)


@njit(cache=True)
def build_cross_lists(query, data, radius):
    """CSR lists of the `data` points within `radius` of each `query` point (two different point sets)."""
    nq = query.shape[0]
    both = np.concatenate((data, query))
    lo, ncell, size = _cell_grid(both, radius)
    d = data.shape[1]
    total = 1
    for a in range(d):
        total *= ncell[a]
    cell = _cell_index(data, lo, ncell, size)
    start, members = _bin(cell, total)
    qcell = _cell_index(query, lo, ncell, size)
    r2max = radius * radius
    nx = ncell[0]
    ny = ncell[1] if d > 1 else 1
    nz = ncell[2] if d > 2 else 1
    ptr = np.zeros(nq + 1, dtype=np.int64)
    for fill in range(2):
        out = np.empty(ptr[nq] if fill else 0, dtype=np.int64)
        for i in range(nq):
            c = qcell[i]
            if d == 1:
                cx, cy, cz = c, 0, 0
            elif d == 2:
                cx, cy, cz = c // ny, c % ny, 0
            else:
                cx, cy, cz = c // (ny * nz), (c // nz) % ny, c % nz
            count = 0
            for ax in range(max(cx - 1, 0), min(cx + 2, nx)):
                for ay in range(max(cy - 1, 0), min(cy + 2, ny)):
                    for az in range(max(cz - 1, 0), min(cz + 2, nz)):
                        cc = (ax * ny + ay) * nz + az
                        for m in range(start[cc], start[cc + 1]):
                            j = members[m]
                            r2 = 0.0
                            for a in range(d):
                                t = query[i, a] - data[j, a]
                                r2 += t * t
                            if r2 < r2max:
                                if fill:
                                    out[ptr[i] + count] = j
                                count += 1
            if not fill:
                ptr[i + 1] = count
        if not fill:
            for i in range(nq):
                ptr[i + 1] += ptr[i]
    return ptr, out
