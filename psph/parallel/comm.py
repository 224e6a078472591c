"""Collective helpers over an mpi4py communicator (every function here communicates)."""

import numpy as np
from mpi4py import MPI


def exclusive_scan(comm, value: int) -> int:
    """Sum of `value` over the ranks below this one (0 on rank 0). Collective."""
    result = comm.exscan(int(value), op=MPI.SUM)
    return 0 if result is None else int(result)


def allreduce_sum(comm, value):
    """Global sum of a number or numpy array. Collective."""
    if isinstance(value, np.ndarray):
        out = np.empty_like(value)
        comm.Allreduce(np.ascontiguousarray(value), out, op=MPI.SUM)
        return out
    return comm.allreduce(value, op=MPI.SUM)


def allreduce_max(comm, value):
    """Global maximum of a number or numpy array. Collective."""
    if isinstance(value, np.ndarray):
        out = np.empty_like(value)
        comm.Allreduce(np.ascontiguousarray(value), out, op=MPI.MAX)
        return out
    return comm.allreduce(value, op=MPI.MAX)


def allreduce_min(comm, value):
    """Global minimum of a number or numpy array. Collective."""
    if isinstance(value, np.ndarray):
        out = np.empty_like(value)
        comm.Allreduce(np.ascontiguousarray(value), out, op=MPI.MIN)
        return out
    return comm.allreduce(value, op=MPI.MIN)


def exchange_counts(comm, send_counts: np.ndarray) -> np.ndarray:
    """Each rank learns how many items every other rank sends it. Collective."""
    recv = np.empty(comm.size, dtype=np.int64)
    comm.Alltoall(np.ascontiguousarray(send_counts, dtype=np.int64), recv)
    return recv


def alltoallv(comm, data: np.ndarray, send_counts: np.ndarray, recv_counts: np.ndarray) -> np.ndarray:
    """Send consecutive blocks of `data` (rows grouped by destination rank) to every rank. Collective.

    data: (n, ...) rows ordered by destination; send_counts/recv_counts: rows per rank.
    Returns the received rows (sum(recv_counts), ...) ordered by source rank.
    """
    if comm.size == 1:  # to itself: a copy, without MPI's per-call cost (a rank's periodic images, migration)
        return np.array(data, copy=True)
    data = np.ascontiguousarray(data)
    tail = data.shape[1:]
    out = np.empty((int(recv_counts.sum()),) + tail, dtype=data.dtype)
    # counts and displacements in rows, of an MPI type one row long: MPI takes them as C ints, and in bytes
    # (or elements) they passed 2^31 from about 10 M rows of a migration (a parallel audit: OverflowError)
    row = MPI.BYTE.Create_contiguous(max(int(np.prod(tail, dtype=np.int64)), 1) * data.dtype.itemsize).Commit()
    try:
        sc = np.asarray(send_counts, dtype=np.int64)
        rc = np.asarray(recv_counts, dtype=np.int64)
        sd = np.concatenate(([0], np.cumsum(sc)[:-1]))
        rd = np.concatenate(([0], np.cumsum(rc)[:-1]))
        comm.Alltoallv([data.view(np.uint8).reshape(-1), (sc, sd), row],
                       [out.view(np.uint8).reshape(-1), (rc, rd), row])
    finally:
        row.Free()
    return out


def on_root(comm, fn):
    """fn() on rank 0 alone, its result given to every rank, or its error raised on every rank, of the same
    type everywhere (a PsphError through raise_if_any; another exception, an OSError, as rank 0's, marked
    `collective`): a file only rank 0 reads (the scene file) or writes (the XDMF index) stops every rank when
    it cannot, not rank 0 alone while the others wait in the next collective (a style audit: a scene file on
    one node's disk). The result is pickled on rank 0 before any rank learns of success, and broadcast as
    bytes in chunks (broadcast_bytes): an unpicklable or huge result (a snapshot of 65 M particles for
    packing.start: mpi4py's pickled bcast stops at 2 GiB) is rank 0's error too, every rank's (a review).
    Collective."""
    import pickle

    if comm.size == 1:
        try:
            return fn()
        except BaseException as exc:
            exc.collective = True  # (as on several ranks: every rank, this one, raises it)
            raise
    payload = error = None
    if comm.rank == 0:
        try:
            payload = pickle.dumps(fn(), protocol=pickle.HIGHEST_PROTOCOL)
        except BaseException as exc:  # any failure, a SystemExit too: the other ranks must learn of it (a review:
            error = exc  # they waited in the broadcast for ever)
    _raise_root_error(comm, error)
    return pickle.loads(broadcast_bytes(comm, payload))


def _raise_root_error(comm, error) -> None:
    """Raise rank 0's `error` (None: none) on every rank, of its type: a PsphError through raise_if_any, any
    other exception pickled (a PsphError naming it where it cannot be). Collective."""
    import pickle

    from psph.errors import PsphError

    blob = None
    if comm.rank == 0 and error is not None and not isinstance(error, PsphError):
        try:
            blob = pickle.dumps(error)
            pickle.loads(blob)  # (an exception whose class cannot be rebuilt from its args)
        except Exception:
            error = PsphError(f"{type(error).__name__}: {error}")
            blob = None
    blob = comm.bcast(blob, root=0)
    if blob is not None:
        err = error if comm.rank == 0 else pickle.loads(blob)
        err.collective = True  # every rank raises it (the CLI: one line, no abort)
        raise err
    raise_if_any(comm, error)


# bytes per Bcast of broadcast_bytes (MPI counts are C ints)
BROADCAST_CHUNK = 2**30


def broadcast_bytes(comm, data) -> bytes:
    """Rank 0's `data` (bytes) on every rank, in Bcast chunks of BROADCAST_CHUNK bytes (no 2 GiB limit).
    Collective."""
    size = comm.bcast(len(data) if comm.rank == 0 else None, root=0)
    buffer = np.frombuffer(data, dtype=np.uint8) if comm.rank == 0 else np.empty(size, dtype=np.uint8)
    for first in range(0, size, BROADCAST_CHUNK):
        comm.Bcast(buffer[first:first + BROADCAST_CHUNK], root=0)
    return data if comm.rank == 0 else buffer.tobytes()


def global_first(comm, local):
    """Of every rank's `local` (None, or (key, gid, payload)), the one of largest key (any comparable value),
    ties to the lowest gid, on every rank; None where no rank has one: the particle a message names is the
    same on any number of ranks (STYLE 4; a style audit found five hand-written copies and two checks that
    named the lowest rank's). Collective."""
    found = [item for item in comm.allgather(local) if item is not None]
    return max(found, key=lambda item: (item[0], -item[1])) if found else None


def raise_if_any(comm, error) -> None:
    """If any rank holds an error, raise the lowest such rank's error on every rank. Collective.

    Lets a check that fails on one rank stop all ranks together instead of leaving them in a collective.
    """
    from psph.errors import WHERE, PsphError, rebuild_error

    local = None if error is None else (type(error), str(error))
    if local is not None and not isinstance(error, PsphError):
        local = (PsphError, f"{type(error).__name__}: {error}")
    where = {k: getattr(error, k) for k in WHERE if getattr(error, k, None) is not None}
    for item, item_where in comm.allgather((local, where)):
        if item is not None:
            err = error if (error is not None and item == local) else rebuild_error(*item, item_where)
            err.collective = True  # every rank raises it: the CLI can exit cleanly
            raise err


def alltoallv_fields(comm, arrays: dict, send_counts: np.ndarray, recv_counts: np.ndarray) -> dict:
    """alltoallv of several arrays with the same rows (grouped by destination rank), in one message: each
    row's values of every array packed side by side as bytes, so that a rebuild's migration or halo costs one
    collective, not one per field. Returns the received arrays by name. Collective."""
    if comm.size == 1 or not arrays:
        return {name: np.array(a, copy=True) for name, a in arrays.items()}
    layout, columns = [], []
    for name, a in arrays.items():
        a = np.ascontiguousarray(a)
        width = int(np.prod(a.shape[1:], dtype=np.int64))
        column = a.reshape(len(a), width).view(np.uint8)  # (n, width * itemsize)
        layout.append((name, a.dtype, a.shape[1:], column.shape[1]))
        columns.append(column)
    received = alltoallv(comm, np.hstack(columns), send_counts, recv_counts)
    out, start = {}, 0
    for name, dtype, tail, nbytes in layout:
        chunk = np.ascontiguousarray(received[:, start:start + nbytes])
        out[name] = chunk.view(dtype).reshape((len(received),) + tail)
        start += nbytes
    return out
