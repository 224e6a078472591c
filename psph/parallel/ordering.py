"""Redistribution of particle data into global gid order (for output and comparisons). Collective."""

import numpy as np

from psph.parallel.comm import alltoallv_fields, exchange_counts


def gid_rows(comm, gid: np.ndarray) -> tuple:
    """Row of each local gid in the global ascending-gid order, and the global count. Collective."""
    counts = np.array(comm.allgather(len(gid)), dtype=np.int64)
    everything = np.empty(int(counts.sum()), dtype=np.int64)
    displs = np.concatenate(([0], np.cumsum(counts)[:-1]))
    comm.Allgatherv(np.ascontiguousarray(gid, dtype=np.int64), [everything, (counts, displs)])
    everything.sort()
    return np.searchsorted(everything, gid), len(everything)


def block_range(total: int, rank: int, size: int) -> tuple:
    """Contiguous block [start, stop) of `total` rows held by `rank` of `size`."""
    return total * rank // size, total * (rank + 1) // size


def to_gid_blocks(comm, gid: np.ndarray, arrays: dict) -> tuple:
    """Send rows so that rank r holds global rows block_range(total, r, size), sorted by gid.

    Returns (start, total, arrays in ascending-gid order for this rank's block). Collective.
    """
    rows, total = gid_rows(comm, gid)
    starts = np.array([block_range(total, r, comm.size)[0] for r in range(comm.size)])
    dest = np.searchsorted(starts, rows, side="right") - 1
    order = np.argsort(dest, kind="stable")
    counts = np.bincount(dest, minlength=comm.size).astype(np.int64)
    recv_counts = exchange_counts(comm, counts)
    got = alltoallv_fields(comm, {"_row": rows[order], **{name: np.asarray(a)[order] for name, a in arrays.items()}},
                           counts, recv_counts)
    local = np.argsort(got.pop("_row"))
    out = {name: a[local] for name, a in got.items()}
    start = block_range(total, comm.rank, comm.size)[0]
    return start, total, out
