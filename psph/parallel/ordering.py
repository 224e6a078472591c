"""Redistribution of particle data into global gid order (for output and comparisons). Collective."""

import numpy as np

from psph.parallel.comm import (
    allreduce_max,
    allreduce_min,
    allreduce_sum,
    alltoallv_fields,
    exchange_counts,
    exclusive_scan,
)


def block_range(total: int, rank: int, size: int) -> tuple:
    """Contiguous block [start, stop) of `total` rows held by `rank` of `size`."""
    return total * rank // size, total * (rank + 1) // size


def to_gid_blocks(comm, gid: np.ndarray, arrays: dict) -> tuple:
    """Send rows so that each rank holds a contiguous block of the global ascending-gid order.

    Rank r receives the gids of the r-th of `size` equal slices of [min gid, max gid] and sorts them; its
    rows start after the ranks below it. One exchange of the data and no rank ever holds every gid (an
    allgather of all gids cost every rank O(N) memory and an O(N log N) sort per snapshot: a parallel
    audit). The blocks are even when the gids are dense, as they are unless an outlet removed many.

    Returns (start, total, arrays in ascending-gid order for this rank's block). Collective.
    """
    gid = np.asarray(gid, dtype=np.int64)
    lo = int(allreduce_min(comm, int(gid.min()) if len(gid) else np.iinfo(np.int64).max))
    hi = int(allreduce_max(comm, int(gid.max()) if len(gid) else -1))
    span = max(hi - lo + 1, 1)
    dest = ((gid - lo) * comm.size) // span if len(gid) else np.zeros(0, dtype=np.int64)
    order = np.argsort(dest, kind="stable")
    counts = np.bincount(dest, minlength=comm.size).astype(np.int64)
    got = alltoallv_fields(comm, {"_gid": gid[order], **{name: np.asarray(a)[order] for name, a in arrays.items()}},
                           counts, exchange_counts(comm, counts))
    local = np.argsort(got.pop("_gid"), kind="stable")
    out = {name: a[local] for name, a in got.items()}
    start = exclusive_scan(comm, len(local))
    return start, int(allreduce_sum(comm, len(local))), out
