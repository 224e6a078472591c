"""Checkpoints: everything a flow or kinematic run needs to continue, written collectively and atomically.

    OUT/checkpoint_NNNNNN.h5   (NNNNNN = step)
        /particles/<field>     every owned field (internal ones too), rank after rank in each rank's
                               local order (so that a restart on as many ranks rebuilds the same lists)
        /state                 JSON (uint8): scene table, step, time, driver counters, history rows,
                               snapshot index, field specs, rank counts, the decomposition
        attrs: format, step, time

Written to a temporary name, fsynced and renamed; older checkpoints are removed only once the new one
is complete, so a run killed at any moment leaves its last complete checkpoint. A restart on the same
number of ranks puts every particle back on its rank in its order, with the saved decomposition, and
continues bit for bit; on another number of ranks the rows are split evenly and rebalanced (results then
agree to round-off, or to solver tolerance with IIPS). There is no random state to save: the only random
numbers (the initial perturbation, the coincident-particle nudge) are drawn from the particles' gids.
"""

import json
import re
from pathlib import Path

import numpy as np

from psph.errors import UsageError
from psph.io.files import jsonable, replace_atomically
from psph.io.snapshots import h5py, write_particle_file
from psph.parallel.comm import allreduce_sum, exclusive_scan
from psph.parallel.decomposition import Decomposition, Split
from psph.parallel.ordering import block_range
from psph.particles import FieldSpec, ParticleSet

FORMAT = "psph-checkpoint-1"
NAME = re.compile(r"checkpoint_(\d{6,})\.h5")  # checkpoint_name's, and no other file's


def checkpoint_name(step: int) -> str:
    return f"checkpoint_{step:06d}.h5"


def _decomposition_table(dec: Decomposition) -> dict:
    return {"splits": [[s.rank_lo, s.rank_hi, s.rank_mid, s.axis, s.value] for s in dec.splits],
            "boxes": [[lo.tolist(), hi.tolist()] for lo, hi in dec.boxes]}


def _decomposition(table: dict) -> Decomposition:
    return Decomposition(splits=tuple(Split(int(a), int(b), int(c), int(ax), float(v))
                                      for a, b, c, ax, v in table["splits"]),
                         boxes=tuple((np.array(lo, dtype=np.float64), np.array(hi, dtype=np.float64))
                                     for lo, hi in table["boxes"]))


def write_checkpoint(comm, out_dir, system, step: int, time: float, state: dict) -> Path:
    """Write the owned particles of `system` and the driver's `state` (JSON-able). Collective."""
    p = system.particles
    counts = comm.allgather(p.n_owned)
    table = dict(state, format=FORMAT, step=int(step), time=float(time), rank_counts=counts,
                 rebuilds=system.rebuilds, decomposition=_decomposition_table(system.decomposition),
                 fields={name: [list(spec.shape), np.dtype(spec.dtype).str] for name, spec in p.specs.items()})
    blob = np.frombuffer(json.dumps(table, default=jsonable).encode(), dtype=np.uint8)
    path = Path(out_dir) / checkpoint_name(step)
    tmp = path.with_name(path.name + ".tmp")
    data = {name: p.owned(name) for name in p.names}
    start = exclusive_scan(comm, p.n_owned)
    total = int(allreduce_sum(comm, p.n_owned))
    write_particle_file(comm, str(tmp), start, total, data, {"format": FORMAT, "step": int(step), "time": float(time)},
                        extra={"state": blob})
    comm.Barrier()
    if comm.rank == 0:
        replace_atomically(tmp, path)
        for old in _checkpoints(out_dir):
            if old != path:
                old.unlink()
    comm.Barrier()
    return path


def read_checkpoint(comm, path) -> tuple:
    """(state, this rank's ParticleSet, saved Decomposition or None). On as many ranks as wrote it, every
    rank gets back its own rows in their order and the decomposition; otherwise an even split and None.
    Raises UsageError for a missing, incomplete or foreign file. Collective."""
    path = Path(path)
    error, state = None, None
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != FORMAT or "state" not in f:
                raise OSError("not a psph checkpoint")
            state = json.loads(bytes(f["state"][()]).decode())
            counts = state["rank_counts"]
            if len(counts) == comm.size:
                start = int(sum(counts[: comm.rank]))
                stop = start + counts[comm.rank]
            else:
                start, stop = block_range(int(sum(counts)), comm.rank, comm.size)
            arrays = {name: f["particles"][name][start:stop] for name in state["fields"]}
    except (OSError, KeyError, ValueError) as exc:
        error = f"cannot restart from {str(path)!r}: {exc}"
    errors = comm.allgather(error)
    if any(errors):
        raise UsageError(next(e for e in errors if e))
    particles = ParticleSet(len(state["decomposition"]["boxes"][0][0]), specs=())
    for name, (shape, dtype) in state["fields"].items():
        particles.add_field(FieldSpec(name, tuple(shape), np.dtype(dtype).type))
    particles.set_owned(arrays)
    same = len(state["rank_counts"]) == comm.size
    return state, particles, (_decomposition(state["decomposition"]) if same else None)


def latest_checkpoint(out_dir):
    """The newest complete checkpoint in `out_dir` (temporary files never count), or None."""
    found = _checkpoints(out_dir)
    return found[-1] if found else None


def _checkpoints(out_dir) -> list:
    """psph's checkpoints in `out_dir`, by step (a step past 999999 has more digits: not by name)."""
    found = [(int(m.group(1)), p) for p in Path(out_dir).iterdir() if (m := NAME.fullmatch(p.name))]
    return [p for _, p in sorted(found)]

