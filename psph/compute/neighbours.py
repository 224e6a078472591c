"""Cell-linked-list neighbour search producing CSR neighbour lists (numba).

The search runs over all local particles (owned + halo) and builds rows for the first `n_rows` particles
(the owned ones). Row i lists every local j != i with |x_i - x_j| < radius, coincident particles
included. The list radius is the kernel support plus a skin, so a list stays valid while no particle has
moved more than half the skin (Verlet list); pairs beyond the support contribute zero in every sum.

Cells are half the list radius wide (a stencil of 5 cells per axis: in 2-D 25 cells of radius^2 / 4
hold 6.25 radius^2 of candidates, against 9 radius^2 for cells of the radius; 15.6 against 27 radius^3
in 3-D). The points are copied into cell order, so a stencil's run of cells along the last axis is one
contiguous slice; the lists are written in one pass without a branch in the inner loop (every candidate
is written, the position advances past those kept) into a buffer sized from the mean density (at most
the candidates' count) and grown when a row's candidates might not fit (3 times faster than the search
over cells of the radius with a distance branch; one pass instead of a counting and a writing pass, 1.4-1.6
times faster again: run_scripts/bench_sums.py).
"""

import numpy as np
from numba import njit

# Cap on the number of cells relative to the particle count: sparse clouds get coarser cells.
_MAX_CELLS_PER_PARTICLE = 4
# Cells per list radius along an axis.
_CELLS_PER_RADIUS = 2
# Relative margin for rounding: cells are made 4 _MARGIN wider than radius / _CELLS_PER_RADIUS, and the
# stencil's reach is ceil(radius / size + _MARGIN), so a pair closer than the radius whose cell indices were
# each rounded by a few ulps still falls inside the stencil, without a stencil one cell wider than needed.
_MARGIN = 1e-6


@njit(cache=True)
def _cell_grid(pos, size):
    """(base, ncell, size): a grid of cells of side `size` (coarsened while the cells would outnumber
    _MAX_CELLS_PER_PARTICLE per point) over `pos`, aligned with the global grid of cells [k size, (k + 1)
    size): its first cell along axis a is base[a] (a whole number, as a float) and a point's cell is
    floor(x / size) - base, so that two ranks put a particle in the same cell of space whatever else they
    hold. The counts are right-aligned in 3 slots (ncell[3 - d:] are the d axes, the rest 1), so that cell
    (a0, a1, a2) is (a0 ncell[1] + a1) ncell[2] + a2 in any dimension and the last used axis is always
    slot 2."""
    n, d = pos.shape
    base = np.zeros(d)
    ncell = np.ones(3, dtype=np.int64)
    if n == 0:
        return base, ncell, size
    lo = np.zeros(d)
    hi = np.zeros(d)
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
        total = 1.0  # in floating point: a runaway particle's extent would overflow an integer product
        for a in range(d):
            total *= np.floor(hi[a] / size) - np.floor(lo[a] / size) + 1.0
        if total <= limit:
            break
        size *= 1.5
    for a in range(d):
        base[a] = np.floor(lo[a] / size)
        ncell[3 - d + a] = int(np.floor(hi[a] / size) - base[a]) + 1
    return base, ncell, size


@njit(cache=True)
def _cell_index(pos, base, ncell, size):
    n, d = pos.shape
    cell = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = 0
        for a in range(d):
            k = int(np.floor(pos[i, a] / size) - base[a])
            k = min(max(k, 0), ncell[3 - d + a] - 1)
            c = c * ncell[3 - d + a] + k
        cell[i] = c
    return cell


@njit(cache=True)
def _bin(cell, ntotal, key):
    """Counting sort of the points by cell, each cell's points by `key` (a particle's gid: a few points per
    cell, an insertion sort): start (ntotal + 1,) and members (points in cell order)."""
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
    for c in range(ntotal):
        for m in range(start[c] + 1, start[c + 1]):
            j = members[m]
            k = m
            while k > start[c] and key[members[k - 1]] > key[j]:  # (stable: images of one gid keep their order)
                members[k] = members[k - 1]
                k -= 1
            members[k] = j
    return start, members


@njit(cache=True, inline="always")
def _stencil(c, ncell, reach):
    """The cell ranges [lo0, hi0), [lo1, hi1), [lo2, hi2) of the stencil around cell c."""
    n0, n1, n2 = ncell[0], ncell[1], ncell[2]
    c2 = c % n2
    c1 = (c // n2) % n1
    c0 = c // (n1 * n2)
    return (max(c0 - reach, 0), min(c0 + reach + 1, n0), max(c1 - reach, 0), min(c1 + reach + 1, n1),
            max(c2 - reach, 0), min(c2 + reach + 1, n2))


@njit(cache=True, inline="always")
def _candidates(start, ncell, lo0, hi0, lo1, hi1, lo2, hi2):
    """The number of points in a stencil."""
    count = 0
    for a0 in range(lo0, hi0):
        for a1 in range(lo1, hi1):
            row = (a0 * ncell[1] + a1) * ncell[2]
            count += start[row + hi2] - start[row + lo2]
    return count


@njit(cache=True)
def _scan(query, n_rows, sorted_pos, members, start, qcell, ncell, reach, r2max, exclude_self, expected):
    """The lists of query points 0..n_rows-1 in one pass: (ptr, idx), idx a view of a buffer at most a quarter
    longer. Each row's candidates (the points of its stencil) are written branch-free, advancing past those
    closer than sqrt(r2max) (without data point i if exclude_self). The buffer starts at `expected` entries
    (capped by the candidates' count), grows by half whenever a row's candidates might not fit, and is copied
    to its length if that is under four fifths of it."""
    n0, n1, n2 = ncell[0], ncell[1], ncell[2]
    rows_in = np.zeros(n0 * n1 * n2, dtype=np.int64)  # query points per cell
    for i in range(n_rows):
        rows_in[qcell[i]] += 1
    bound = 0  # the candidates' count, cell by cell
    for c in range(rows_in.size):
        if rows_in[c]:
            lo0, hi0, lo1, hi1, lo2, hi2 = _stencil(c, ncell, reach)
            bound += rows_in[c] * _candidates(start, ncell, lo0, hi0, lo1, hi1, lo2, hi2)
    idx = np.empty(int(min(expected, bound)) + 1, dtype=np.int32)
    ptr = np.zeros(n_rows + 1, dtype=np.int64)
    out = 0
    x = np.zeros(3)
    for i in range(n_rows):
        lo0, hi0, lo1, hi1, lo2, hi2 = _stencil(qcell[i], ncell, reach)
        candidates = _candidates(start, ncell, lo0, hi0, lo1, hi1, lo2, hi2)
        if out + candidates >= idx.size:
            grown = np.empty(max(out + candidates + 1, idx.size + idx.size // 2), dtype=np.int32)
            grown[:out] = idx[:out]
            idx = grown
        for a in range(query.shape[1]):
            x[a] = query[i, a]
        x0, x1, x2 = x[0], x[1], x[2]
        for a0 in range(lo0, hi0):
            for a1 in range(lo1, hi1):
                row = (a0 * n1 + a1) * n2
                for m in range(start[row + lo2], start[row + hi2]):
                    t0 = x0 - sorted_pos[m, 0]
                    t1 = x1 - sorted_pos[m, 1]
                    t2 = x2 - sorted_pos[m, 2]
                    j = members[m]
                    idx[out] = j  # write always, advance when kept: no branch in the inner loop
                    out += t0 * t0 + t1 * t1 + t2 * t2 < r2max and not (exclude_self and j == i)
        ptr[i + 1] = out
    if 4 * idx.size > 5 * out + 64:
        return ptr, idx[:out].copy()
    return ptr, idx[:out]


# the lists' indices are int32 (half the memory of int64; the search, the fluid's pair cache and the IIPS
# operator read them): a rank holds fewer particles, halo included
INDEX_LIMIT = 2**31 - 1

# Volume of the unit ball in 1-3 D (the first guess of a list's length)
_BALL = (2.0, np.pi, 4.0 / 3.0 * np.pi)


@njit(cache=True)
def _lists(query, n_rows, data, radius, exclude_self, key):
    """CSR lists of the `data` points within `radius` (> 0) of query points 0..n_rows-1, in cell order (the
    global grid's, _cell_grid), each cell's points by `key`; with exclude_self, query i is data i and is
    left out of its own row."""
    if not radius > 0.0:
        raise ValueError("the neighbour-list radius must be positive")
    if data.shape[0] > INDEX_LIMIT:
        raise ValueError("more local particles than 32-bit neighbour indices address")
    d = data.shape[1]
    base, ncell, size = _cell_grid(np.concatenate((data, query[:n_rows])),
                                   radius / _CELLS_PER_RADIUS * (1.0 + 4.0 * _MARGIN))
    reach = int(np.ceil(radius / size + _MARGIN))
    start, members = _bin(_cell_index(data, base, ncell, size), ncell[0] * ncell[1] * ncell[2], key)
    qcell = _cell_index(query[:n_rows], base, ncell, size)
    # the data in cell order, padded to three coordinates
    sorted_pos = np.zeros((members.size, 3))
    for m in range(members.size):
        for a in range(d):
            sorted_pos[m, a] = data[members[m], a]
    # first guess of the lists' length: the mean density over the grid times the ball's volume, 10% more (in
    # cells, so that no scale of the coordinates overflows)
    expected = 1.1 * n_rows * members.size * _BALL[d - 1] * (radius / size) ** d / (ncell[0] * ncell[1] * ncell[2])
    return _scan(query, n_rows, sorted_pos, members, start, qcell, ncell, reach, radius * radius, exclude_self,
                 expected)


def build_neighbour_lists(pos, n_rows, radius, gid=None):
    """CSR neighbour lists (ptr, idx) of rows 0..n_rows-1 over all particles in `pos`.

    pos: (n, d) positions of owned then halo particles; radius: list radius (support + skin); gid: the
    particles' global ids (None: their rows). Returns ptr (n_rows + 1,) int64 and idx (ptr[-1],) int32 (a
    view of a buffer at most a quarter longer); row i is idx[ptr[i]:ptr[i+1]], j != i, in the order of the
    cells of space around i (_cell_grid), each cell's particles by gid: the same order on every rank count,
    so that a particle's sums are too, to the last bit (unless a rank's grid was coarsened: _cell_grid).

    (This and build_cross_lists call _lists from Python, where exclude_self is a bool: from a numba function
    each constant would be a literal type, and the search compiled once for each, 9 s more on a cold cache.)
    """
    key = np.arange(len(pos), dtype=np.int64) if gid is None else np.ascontiguousarray(gid, dtype=np.int64)
    return _lists(pos, int(n_rows), pos, float(radius), True, key)


def build_cross_lists(query, data, radius):
    """CSR lists of the `data` points within `radius` of each `query` point (two different point sets)."""
    return _lists(query, query.shape[0], data, float(radius), False, np.arange(len(data), dtype=np.int64))


@njit(cache=True, inline="always")
def _image_near(pos, i, shift, lo, hi, radius):
    """Whether the image pos[i] + shift lies strictly within `radius` of the box (lo, hi)."""
    for a in range(pos.shape[1]):
        x = pos[i, a] + shift[a]
        if not (x > lo[a] - radius and x < hi[a] + radius):
            return False
    return True


@njit(cache=True)
def image_rows(pos, box_lo, box_hi, shifts, skip, radius):
    """The rows of `pos` whose image pos + shifts[s] lies within `radius` of box r (strictly inside box r
    widened by radius on every side), for every box r and shift s with skip[r, s] False.

    box_lo, box_hi: (n_boxes, d) (+-inf allowed); shifts: (n_shifts, d). Returns (rows, shift numbers,
    counts per box), grouped by box, then by shift, then by ascending row. An image outside the boxes' union
    widened by radius is tested against no box (most particles have only the zero shift to test)."""
    n = pos.shape[0]
    nb, ns = skip.shape
    union_lo = box_lo[0].copy()
    union_hi = box_hi[0].copy()
    for r in range(1, nb):
        union_lo = np.minimum(union_lo, box_lo[r])
        union_hi = np.maximum(union_hi, box_hi[r])
    counts = np.zeros((nb, ns), dtype=np.int64)
    for fill in (False, True):
        if fill:
            offset = np.zeros(nb * ns + 1, dtype=np.int64)
            offset[1:] = np.cumsum(counts.ravel())
            rows = np.empty(offset[-1], dtype=np.int64)
            which = np.empty(offset[-1], dtype=np.int64)
            at = offset[:-1].copy()
        for i in range(n):
            for s in range(ns):
                if not _image_near(pos, i, shifts[s], union_lo, union_hi, radius):
                    continue
                for r in range(nb):
                    if skip[r, s] or not _image_near(pos, i, shifts[s], box_lo[r], box_hi[r], radius):
                        continue
                    if fill:
                        k = at[r * ns + s]
                        rows[k] = i
                        which[k] = s
                        at[r * ns + s] = k + 1
                    else:
                        counts[r, s] += 1
    return rows, which, counts.sum(axis=1)


@njit(cache=True)
def spatial_order(pos, cell_size):
    """Permutation that sorts particles cell by cell (row-major cells of side `cell_size`).

    Applied to owned particles after each neighbour-list rebuild so that neighbours sit close in memory.
    """
    base, ncell, size = _cell_grid(pos, cell_size)
    cell = _cell_index(pos, base, ncell, size)
    return np.argsort(cell, kind="mergesort")


@njit(cache=True)
def closest_pair(pos, flagged, ptr, idx):
    """(distance, row) of the closest pair over the owned rows' lists with at least one flagged particle
    (inf, -1 if none). pos, flagged: every local particle's."""
    best, row = np.inf, -1
    d = pos.shape[1]
    for i in range(ptr.size - 1):
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if not (flagged[i] or flagged[j]):
                continue
            r2 = 0.0
            for a in range(d):
                t = pos[i, a] - pos[j, a]
                r2 += t * t
            if r2 < best:
                best, row = r2, i
    return np.sqrt(best), row


@njit(cache=True)
def max_displacement(pos, ref, n):
    """max_i |pos_i - ref_i| over the first n particles; infinite if a position is not finite (NaN compares
    false, so such a particle passed for one that had not moved)."""
    d = pos.shape[1]
    m = 0.0
    for i in range(n):
        r2 = 0.0
        for a in range(d):
            t = pos[i, a] - ref[i, a]
            r2 += t * t
        if not r2 < np.inf:
            return np.inf
        if r2 > m:
            m = r2
    return np.sqrt(m)


@njit(cache=True)
def coincident_rows(pos, gid, ptr, idx, tol):
    """Owned rows i with a neighbour j closer than `tol` and gid_j < gid_i (one of each close pair), and the
    smallest squared distance |x_i - x_j|^2 over the pairs it measured (those with gid_j < gid_i, each row's up to
    its first close pair; inf for none): system.ParticleSystem.separate_coincident skips the next search while the
    particles have not moved enough since to bring any of these pairs within `tol`."""
    d = pos.shape[1]
    out = np.zeros(ptr.size - 1, dtype=np.bool_)
    closest = np.inf
    for i in range(ptr.size - 1):
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if gid[j] >= gid[i]:
                continue
            r2 = 0.0
            for a in range(d):
                t = pos[i, a] - pos[j, a]
                r2 += t * t
            if r2 < closest:
                closest = r2
            if r2 < tol * tol:
                out[i] = True
                break
    return np.flatnonzero(out), closest
