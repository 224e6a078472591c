"""Checkpoints: everything a flow or kinematic run needs to continue, written collectively and atomically.

    OUT/checkpoint_NNNNNN.h5   (NNNNNN = step)
        /particles/<field>     every owned field (internal ones too), rank after rank in each rank's
                               local order (so that a restart on as many ranks rebuilds the same lists)
        /state                 JSON (uint8): scene table, step, time, driver counters, history rows,
                               snapshot index, field specs, rank counts, the decomposition
        attrs: format, step, time
        every dataset with a Fletcher32 checksum per chunk: a restart refuses a damaged one, naming it
    and, in its first SEAL_BYTES (an HDF5 user block, which HDF5 skips), the CRC32 and length of the rest
    of the file: a restart checks them before HDF5 reads a byte (a fuzzing audit: flipped bits in HDF5's
    own metadata could crash HDF5's reader, 2 of about 3000 flips)

Written to a temporary name, fsynced and renamed; the run's previous checkpoint (or, on a restart, the
continued run's ones up to the restart) is removed only once the new one is complete, so a run killed at
any moment leaves its last complete checkpoint; no other file is ever removed. A restart on the same
number of ranks puts every particle back on its rank in its order, with the saved decomposition, and
continues bit for bit; on another number of ranks the rows are split evenly and rebalanced (results then
agree to round-off, or to solver tolerance with IIPS). There is no random state to save: the only random
numbers (the initial perturbation, the coincident-particle nudge) are drawn from the particles' gids.
"""

import json
import re
import zlib
from pathlib import Path

import numpy as np

from psph.errors import SceneError, UsageError, point
from psph.io.files import jsonable, replace_atomically
from psph.io.snapshots import SNAPSHOT_NAME, h5py, write_particle_file
from psph.parallel.comm import allreduce_sum, exclusive_scan, global_first, on_root
from psph.parallel.decomposition import Decomposition, Split
from psph.parallel.ordering import block_range
from psph.particles import SCRATCH_FIELDS, FieldSpec, Kind, ParticleSet
from psph.scene.load import scene_from_table

FORMAT = "psph-checkpoint-1"
NAME = re.compile(r"checkpoint_(\d{6,})\.h5")  # checkpoint_name's, and no other file's
PARTIAL = re.compile(r"checkpoint_(\d{6,})\.h5\.tmp")  # one being written (left by a kill during the write)


SEAL_BYTES = 512
SEAL = b"psph-seal-1 crc32 "
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def _crc32(path, start) -> tuple:
    """(CRC32, length) of the file's bytes from `start` on."""
    crc, size = 0, 0
    with open(path, "rb") as f:
        f.seek(start)
        while chunk := f.read(1 << 24):
            crc, size = zlib.crc32(chunk, crc), size + len(chunk)
    return crc, size


def seal(path) -> None:
    """Write the CRC32 and length of a checkpoint's HDF5 contents into its user block."""
    crc, size = _crc32(path, SEAL_BYTES)
    with open(path, "r+b") as f:
        f.write(SEAL + f"{crc:08x} {size}\n".encode())


def seal_damage(path):
    """Why the file at `path` is not a whole sealed checkpoint (its contents or their length are not those
    sealed), or None: it matches, has no seal (an older psph's checkpoint, whose HDF5 signature is at its
    start) or cannot be read (read_checkpoint says why)."""
    try:
        with open(path, "rb") as f:
            head = f.read(SEAL_BYTES)
        if head.startswith(HDF5_SIGNATURE):
            return None
        sealed = re.fullmatch(rb"([0-9a-f]{8}) ([0-9]+)", head[len(SEAL):].split(b"\n")[0])
        if not head.startswith(SEAL) or not sealed:
            return "its first block is damaged or it is not a psph checkpoint"
        if _crc32(path, SEAL_BYTES) != (int(sealed.group(1), 16), int(sealed.group(2))):
            return "it is damaged: its bytes differ from those written (the CRC32 of the file fails)"
    except OSError:
        pass
    return None


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


def write_checkpoint(comm, out_dir, system, step: int, time: float, state: dict, replaces=()) -> Path:
    """Write the owned particles of `system` and the driver's `state` (JSON-able), then remove the
    checkpoints `replaces` (rank 0's list: the run's own earlier ones), and no other file. Collective."""
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
    try:
        # (libver "latest": the metadata's checksums too; a fuzzing audit: of one-bit flips of a checkpoint
        # written without, 57 changed the restart's fields unnoticed, 8 raised a traceback, 1 hung)
        write_particle_file(comm, str(tmp), start, total, data,
                            {"format": FORMAT, "step": int(step), "time": float(time)}, extra={"state": blob},
                            libver="latest", userblock=SEAL_BYTES)
        comm.Barrier()  # (every rank's writes closed before rank 0 reads the file back for the seal)
        on_root(comm, lambda: seal(tmp))  # (its failure is every rank's, a style audit)
    except BaseException:  # (a full disk) no partial checkpoint is left; the previous one stays
        if comm.rank == 0:
            tmp.unlink(missing_ok=True)
        raise
    def publish():
        replace_atomically(tmp, path)
        for old in replaces:
            if Path(old) != path:
                Path(old).unlink(missing_ok=True)

    on_root(comm, publish)
    return path


# what every checkpoint's state holds (write_checkpoint and Simulation.checkpoint), and what the drivers'
# checkpoint() methods add under "driver" and read back on a restart (FluidDriver, KinematicDriver)
STATE_KEYS = {"scene": dict, "step": int, "time": float, "rank_counts": list, "rebuilds": int,
              "decomposition": dict, "fields": dict, "history": list, "snapshots": list, "driver": dict}
DRIVER_KEYS = ("step", "time", "totals", "next_output")
KINEMATIC_DRIVER_KEYS = ("report", "pre", "shifting")
FLUID_DRIVER_KEYS = ("first_dt", "initial_volume", "iips")


def _check_state(state) -> None:
    """Raise ValueError naming the first key of a checkpoint's state that is missing or of the wrong type."""
    if not isinstance(state, dict):
        raise ValueError("its state is not a table")
    for key, kind in STATE_KEYS.items():
        if key not in state:
            raise ValueError(f"its state lacks {key!r}")
        value = state[key]
        ok = (isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)
              if kind is float else isinstance(value, kind) and not isinstance(value, bool))
        if not ok:
            raise ValueError(f"its state's {key!r} is not {'a finite number' if kind is float else kind.__name__}")
    physics = state["scene"].get("physics")
    scheme = physics.get("scheme") if isinstance(physics, dict) else None
    extra = KINEMATIC_DRIVER_KEYS if scheme == "kinematic" else FLUID_DRIVER_KEYS
    for key in DRIVER_KEYS + extra:
        if key not in state["driver"]:
            raise ValueError(f"its state's 'driver' lacks {key!r}")
    retry = state["driver"].get("retry", [0, 0])  # fluid runs since time.retries' recovery (older: none)
    if not (isinstance(retry, list) and len(retry) == 2 and all(type(v) is int and v >= 0 for v in retry)):
        raise ValueError("its state's 'driver' 'retry' is not two counts")
    if not isinstance(state.get("run", ""), str):  # (a checkpoint of an older psph has no run id)
        raise ValueError("its state's 'run' is not a run id")
    counts = state["rank_counts"]
    if not counts or not all(isinstance(c, int) and c >= 0 for c in counts):
        raise ValueError("its state's 'rank_counts' are not counts of particles")
    if not all(isinstance(row, dict) and "time" in row for row in state["history"]):
        raise ValueError("its state's 'history' has a row without a time")
    if not all(isinstance(entry, list) and len(entry) == 5 for entry in state["snapshots"]):
        raise ValueError("its state's 'snapshots' index is malformed")
    for name in ("position", "gid"):
        if name not in state["fields"]:
            raise ValueError(f"its state lists no field {name!r}")


# fields every particle holds a positive value of (a run stops before one turns negative)
POSITIVE = ("volume", "mass", "density")


def _check_rows(f, arrays, start, gids=False) -> None:
    """Raise ValueError for a kind that is no Kind or a POSITIVE field's value <= 0 in this rank's rows (from
    row `start`), and, with `gids`, for gids that are not unique over the whole file (read by one rank:
    read_checkpoint passes every rank's error to all)."""
    if gids:
        every = _read(f["particles"]["gid"], np.s_[:], "particles/gid")
        unique, counts = np.unique(every, return_counts=True)
        if len(unique) < len(every):
            raise ValueError(f"particles/gid repeats gid {unique[np.argmax(counts)]}")
    if "kind" in arrays:
        bad = ~np.isin(arrays["kind"], [k.value for k in Kind])
        if bad.any():
            raise ValueError(f"particles/kind holds {arrays['kind'][bad][0]}, which is no particle kind")
    for name in POSITIVE:
        if name in arrays and (arrays[name] <= 0.0).any():
            row = int(np.argmax(arrays[name] <= 0.0))
            raise ValueError(f"particles/{name} holds {arrays[name][row]:g} in row {start + row}, not > 0")


def _read(ds, selection, what) -> np.ndarray:
    """ds[selection]; ValueError naming `what` if it is no dataset or HDF5 cannot read it (a chunk failing its
    checksum)."""
    _dataset(ds, what)
    try:
        return ds[selection]
    except OSError as exc:
        reason = "its Fletcher32 checksum fails" if "fletcher32" in str(exc).lower() else " ".join(str(exc).split())
        raise ValueError(f"{what} is damaged: {reason}") from None


def _dataset(node, what):
    """`node` if it is an HDF5 dataset; ValueError naming `what` else (damaged metadata can make a link name
    a datatype: a fuzzing audit's traceback)."""
    if not isinstance(node, h5py.Dataset):
        raise ValueError(f"{what} is not a dataset (the file is damaged)")
    return node


def _read_rows(f, state, name, start, stop, dim) -> np.ndarray:
    """Rows [start, stop) of /particles/<name>, checked against the state's field list: shape, type, and
    (floating fields) finite values; ValueError names the field otherwise."""
    shape, dtype = state["fields"][name]
    dtype = np.dtype(dtype)
    total = int(sum(state["rank_counts"]))
    tail = tuple(dim if s == "d" else int(s) for s in shape)
    if "particles" not in f or name not in f["particles"]:
        raise ValueError(f"it has no dataset particles/{name}")
    ds = _dataset(f["particles"][name], f"particles/{name}")
    if ds.shape != (total,) + tail:
        raise ValueError(f"particles/{name} has shape {ds.shape}, expected {(total,) + tail}")
    if ds.dtype != dtype:
        raise ValueError(f"particles/{name} holds {ds.dtype}, expected {dtype}")
    rows = _read(ds, np.s_[start:stop], f"particles/{name}")
    if dtype.kind in "fc":
        bad = ~np.isfinite(rows)
        if bad.any():
            row = int(np.argwhere(bad)[0][0])
            raise ValueError(f"particles/{name} holds a non-finite value ({rows[row][bad[row]].flat[0]} in "
                             f"row {start + row})")
    return rows


def read_checkpoint(comm, path) -> tuple:
    """(state, this rank's ParticleSet, saved Decomposition or None). On as many ranks as wrote it, every
    rank gets back its own rows in their order and the decomposition; otherwise an even split and None.
    Raises UsageError (one line naming the file and what is wrong, on every rank) for a missing,
    incomplete, foreign or inconsistent file: a state key missing, a field of the wrong shape or type, a
    non-finite value in a floating field (a NaN position would stall the neighbour search). Collective."""
    path = Path(path)
    error, result = None, None
    damage = comm.bcast(seal_damage(path) if comm.rank == 0 and path.is_file() else None, root=0)
    try:
        if damage:
            raise OSError(damage)
        if path.is_dir():
            latest = latest_checkpoint(path)
            raise OSError("a directory, not a checkpoint file"
                          + (f" (its latest checkpoint is {latest})" if latest else ""))
        if not path.exists():
            raise OSError("no such file")
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != FORMAT or "state" not in f:
                raise OSError("not a psph checkpoint")
            state = json.loads(bytes(_read(f["state"], (), "its state")).decode())
            _check_state(state)
            _keep_old_walls(state["scene"])
            _keep_old_lind(state["scene"])
            _keep_old_inflow(state["scene"])
            boxes = state["decomposition"]["boxes"]
            dim = len(boxes[0][0])
            counts = state["rank_counts"]
            if len(counts) == comm.size:
                start = int(sum(counts[: comm.rank]))
                stop = start + counts[comm.rank]
            else:
                start, stop = block_range(int(sum(counts)), comm.rank, comm.size)
            arrays = {name: _read_rows(f, state, name, start, stop, dim) for name in state["fields"]}
            _check_rows(f, arrays, start, gids=comm.rank == 0)
        particles = ParticleSet(dim, specs=())
        for name, (shape, dtype) in state["fields"].items():
            particles.add_field(FieldSpec(name, tuple(shape), np.dtype(dtype).type, scratch=name in SCRATCH_FIELDS))
        particles.set_owned(arrays)
        same = len(counts) == comm.size
        result = state, particles, (_decomposition(state["decomposition"]) if same else None)
    # RuntimeError: h5py's for damaged HDF5 metadata ("bad local heap signature"); not its subclasses
    # (RecursionError, NotImplementedError: bugs)
    except (OSError, RuntimeError, KeyError, ValueError, TypeError, IndexError, UnicodeDecodeError) as exc:
        if isinstance(exc, RuntimeError) and type(exc) is not RuntimeError:
            raise
        reason = str(exc) if not isinstance(exc, KeyError) else f"{exc} missing"
        error = f"cannot restart from {str(path)!r}: {' '.join(reason.split())}"  # HDF5's text has newlines
    errors = comm.allgather(error)
    if any(errors):
        raise UsageError(next(e for e in errors if e))
    return result


def _keep_old_lind(table: dict) -> None:
    """A checkpoint written before shifting.lind_diffusion existed ran Lind's law with shifting.diffusion
    (0.4 h^2 by default; a review: it continued at the new key's 0.2, and a restart cannot change shifting
    keys). read_checkpoint applies it to the state's scene."""
    shifting = table.get("shifting")
    if isinstance(shifting, dict) and shifting.get("method") == "lind" and "lind_diffusion" not in shifting:
        shifting["lind_diffusion"] = shifting.get("diffusion", 0.4)


def _keep_old_inflow(table: dict) -> None:
    """A checkpoint written while inflow.density defaulted to "prescribed" (before 2026-11-30) and did not
    set it continues with it (the new default would change the physics mid-run; a review). read_checkpoint
    applies it to the state's scene."""
    for inflow in table.get("inflow") or []:
        if isinstance(inflow, dict) and "density" not in inflow:
            inflow["density"] = "prescribed"


def _keep_old_walls(table: dict) -> None:
    """A checkpoint written before physics.wall_adhesion existed ran with seed 004's walls everywhere: its
    continuation keeps them (the key's default would change the physics mid-run), where the key applies.
    read_checkpoint applies it to the state's scene."""
    physics = table.setdefault("physics", {})
    if "wall_adhesion" in physics:
        return
    physics["wall_adhesion"] = True
    try:
        scene_from_table(table)
    except SceneError as err:
        if err.key == "physics.wall_adhesion":  # no clone walls or no free surface: the key does not apply
            del physics["wall_adhesion"]


def check_positions(comm, path, particles, domain) -> None:
    """Refuse a checkpoint whose particles lie outside its scene's `domain` along a closed axis (a damaged
    or edited file: a run writes its checkpoints after the escape check), naming the count and the first such
    particle, as a UsageError on every rank. Collective."""
    pos, gids = particles.owned("position"), particles.owned("gid")
    out = np.flatnonzero(domain.outside(pos))
    k = out[np.argmin(gids[out])] if len(out) else None
    first = global_first(comm, (0, int(gids[k]), point(pos[k])) if k is not None else None)  # the lowest gid
    count = int(allreduce_sum(comm, len(out)))
    if count:
        _, gid, at = first
        raise UsageError(f"cannot restart from {str(path)!r}: {count} particle(s) outside the scene's domain "
                         f"(gid {gid} at {at})")


def latest_checkpoint(out_dir):
    """The newest complete checkpoint in `out_dir` (temporary files never count), or None."""
    found = _checkpoints(out_dir)
    return found[-1] if found else None


def _checkpoints(out_dir) -> list:
    """psph's checkpoints in `out_dir`, by step (a step past 999999 has more digits: not by name)."""
    found = [(int(m.group(1)), p) for p in Path(out_dir).iterdir() if (m := NAME.fullmatch(p.name))]
    return [p for _, p in sorted(found)]


def checkpoints_up_to(out_dir, step: int) -> list:
    """psph's checkpoints in `out_dir` of steps up to `step`: on a restart, the continued run's own, which the
    continuation's first checkpoint replaces."""
    return [p for p in _checkpoints(out_dir) if _step(p) <= step]


def _step(path) -> int:
    return int(NAME.fullmatch(Path(path).name).group(1))


def results_after(out_dir, state) -> tuple:
    """What `out_dir` holds past the checkpoint `state` (read_checkpoint's), which continuing from it there
    replaces: (final, partial). final: a finished run's summary.json and later checkpoints (a continuation
    that failed early would leave them contradicting the rest; continuing needs --overwrite); partial: the
    snapshots past the checkpoint's snapshot index (an interrupted run's, which the continuation writes
    again) and the temporary files of later checkpoints that a kill left half written. The history's later
    rows need no list: Simulation rewrites history.csv from the checkpoint's."""
    from psph.io.history import SUMMARY_NAME

    out_dir = Path(out_dir)
    final = [p for p in _checkpoints(out_dir) if _step(p) > state["step"]]
    if (out_dir / SUMMARY_NAME).exists():
        final.insert(0, out_dir / SUMMARY_NAME)
    partial = []
    for p in sorted(out_dir.iterdir()):
        m = SNAPSHOT_NAME.fullmatch(p.name)
        if m and int(m.group(1)) >= len(state["snapshots"]):
            partial.append(p)
        m = PARTIAL.fullmatch(p.name)
        if m and int(m.group(1)) > state["step"]:
            partial.append(p)
    return final, partial
