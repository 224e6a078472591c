"""Snapshots: collective parallel HDF5 in gid order, indexed by an XDMF time series for ParaView.

Output contract (read by tools and tests; keep stable):
    OUT/snapshot_NNNNNN.h5   /particles/position (n x d, rows in ascending gid), /particles/gid,
                             /particles/kind, one dataset per field; attributes `time`, `step`
    OUT/psph.xdmf            temporal collection of the snapshots in OUT (ParaView: File > Open, Xdmf Reader)
Every dataset carries HDF5's Fletcher32 checksum (any HDF5 reader checks it, and fails on a damaged chunk
rather than return its bytes). Each file is written to a temporary name and renamed once complete. The
XDMF lists only snapshot files in its own directory: a run continued from a checkpoint into another
directory starts its series there at the checkpoint (the earlier snapshots stay in the original directory,
listed by its own psph.xdmf).
"""

import errno
import os
import re
from pathlib import Path

import numpy as np

from psph.io.files import replace_atomically, write_text_atomic
from psph.parallel.comm import on_root
from psph.parallel.ordering import to_gid_blocks

# Debian's h5py picks its MPI build only under mpiexec unless told otherwise; psph always wants it.
os.environ.setdefault("H5PY_ALWAYS_USE_MPI", "1")
import h5py  # noqa: E402

XDMF_NAME = "psph.xdmf"
SNAPSHOT_NAME = re.compile(r"snapshot_(\d{6,})\.h5(?:\.tmp)?")  # snapshot_name's (and its temporary file)


def h5py_has_mpi() -> bool:
    return bool(h5py.get_config().mpi)


def snapshot_name(index: int) -> str:
    return f"snapshot_{index:06d}.h5"


def snapshot_files(directory) -> list:
    """The complete snapshot files in `directory`, in the order written (by index: a name sort put
    snapshot_1000000.h5 before snapshot_999999.h5)."""
    found = [(SNAPSHOT_NAME.fullmatch(p.name), p) for p in Path(directory).glob("snapshot_*.h5")]
    return [p for _, p in sorted((int(m.group(1)), p) for m, p in found if m)]


def foreign_snapshots(directory, run) -> list:
    """The snapshot files in `directory` stamped with another run's id than `run` (unstamped files, and
    every file when `run` is None, are an older psph's: not counted)."""
    if not run:
        return []
    foreign = []
    for path in snapshot_files(directory):
        try:
            with h5py.File(path, "r") as f:
                stamp = f.attrs.get("run")
        except (OSError, KeyError, RuntimeError, ValueError):  # (h5py's words for a damaged file, whose
            continue  # metadata a flipped bit broke, a review found: the continuation reads none of it)
        if stamp is not None and (stamp.decode() if isinstance(stamp, bytes) else str(stamp)) != run:
            foreign.append(path)
    return foreign


def _write_rows(ds, start, arr) -> None:
    """Write `arr` to rows [start, start + len(arr)) of `ds` in one collective MPI-IO call, which every rank
    must make: h5py's ds[a:a] = arr returns without one for an empty block (a rank holding no particle, as
    when there are fewer particles than ranks), and the other ranks then waited in it for ever."""
    dxpl = h5py.h5p.create(h5py.h5p.DATASET_XFER)
    dxpl.set_dxpl_mpio(h5py.h5fd.MPIO_COLLECTIVE)
    file_space = ds.id.get_space()
    if len(arr):
        file_space.select_hyperslab((start,) + (0,) * (arr.ndim - 1), arr.shape)
        memory_space = h5py.h5s.create_simple(arr.shape)
    else:  # nothing to write, but the call all the same
        file_space.select_none()
        arr = np.zeros((1,) + arr.shape[1:], dtype=arr.dtype)
        memory_space = h5py.h5s.create_simple(arr.shape)
        memory_space.select_none()
    ds.id.write(memory_space, file_space, arr, dxpl=dxpl)


CHUNK_BYTES = 1 << 20  # a checksummed dataset's chunks: about 1 MiB each


def _checksummed(shape, dtype) -> dict:
    """create_dataset's arguments for a dataset with a Fletcher32 checksum per chunk (chunks of whole rows, at
    most about CHUNK_BYTES, of equal size so that the last, which HDF5 stores whole, holds fewer unused rows
    than there are chunks), or none for an empty or 0-d one (HDF5 chunks only non-empty arrays)."""
    if not shape or 0 in shape:
        return {}
    row = max(1, int(np.prod(shape[1:], dtype=np.int64)) * np.dtype(dtype).itemsize)
    chunks = -(-shape[0] * row // CHUNK_BYTES)
    return {"chunks": (-(-shape[0] // chunks),) + tuple(shape[1:]), "fletcher32": True}


def write_particle_file(comm, path, start, total, data, attrs, extra=None, libver=None, userblock=0) -> None:
    """HDF5 file with /particles/<name> datasets (this rank's rows of `data` at [start, start + len)),
    file attributes `attrs` and root datasets `extra` (rank 0's values: every rank must create the same
    datasets), each with a Fletcher32 checksum; libver = "latest" checksums HDF5's own metadata too (files
    HDF5 1.10 and later read); `userblock` bytes are left free at the start (psph.io.checkpoint's seal).
    Collective: parallel HDF5 (whose writes to a filtered
    dataset must be collective: rank 0 writes `extra`, the others an empty block), or, for an h5py without
    MPI, rank 0 gathers the blocks (in rank order) and writes."""
    extra = comm.bcast(extra or {}, root=0)
    _check_space(comm, path, data, extra)
    try:
        _write_particle_file(comm, path, start, total, data, attrs, extra,
                             {"libver": libver} | ({"userblock_size": userblock} if userblock else {}))
    except (ValueError, RuntimeError) as err:  # h5py's words for a write the system refused (a full disk)
        if "write failed" not in str(err) and "errno" not in str(err):
            raise
        raise OSError(f"writing {path} failed: {' '.join(str(err).split())}") from err


# room a particle file needs beyond its arrays: HDF5's metadata, the chunk index and checksums
FILE_OVERHEAD = 1.05, 2**16


def _check_space(comm, path, data, extra) -> None:
    """Refuse a write the disk cannot hold before it starts, on every rank alike (a write that fails half-way
    leaves the ranks of a parallel HDF5 file waiting for each other in its collective close). Collective."""
    need = comm.allreduce(sum(np.asarray(a).nbytes for a in data.values()))
    need = FILE_OVERHEAD[0] * (need + sum(np.asarray(a).nbytes for a in extra.values())) + FILE_OVERHEAD[1]
    free = error = None
    if comm.rank == 0:
        try:
            stat = os.statvfs(Path(path).parent)
            # root may use the reserved blocks too; a file system that counts no blocks (an unlimited tmpfs,
            # some network ones) says nothing: not checked
            blocks = stat.f_bfree if os.geteuid() == 0 else stat.f_bavail
            free = blocks * stat.f_frsize if stat.f_blocks else None
        except OSError as err:  # (the directory taken away: every rank raises it, none waits)
            error = err
    free, error = comm.bcast((free, error), root=0)
    if error is not None:
        raise error
    if free is not None and free < need:
        raise OSError(errno.ENOSPC, f"No space left on device: {path} needs about {need / 2**20:.1f} MiB, "
                      f"{free / 2**20:.1f} MiB are free")


def _write_particle_file(comm, path, start, total, data, attrs, extra, options) -> None:
    if h5py_has_mpi():
        with h5py.File(path, "w", driver="mpio", comm=comm, **options) as f:
            grp = f.create_group("particles")
            for name, arr in data.items():
                shape = (total,) + arr.shape[1:]
                ds = grp.create_dataset(name, shape=shape, dtype=arr.dtype, **_checksummed(shape, arr.dtype))
                if total:  # HDF5 refuses a write to a dataset of no rows (every rank knows `total`)
                    _write_rows(ds, start, np.ascontiguousarray(arr))
            for name, arr in extra.items():
                ds = f.create_dataset(name, shape=arr.shape, dtype=arr.dtype, **_checksummed(arr.shape, arr.dtype))
                if arr.ndim == 0:  # not chunked, so not filtered: rank 0 alone may write it
                    if comm.rank == 0:
                        ds[()] = arr
                elif arr.size:
                    _write_rows(ds, 0, np.ascontiguousarray(arr if comm.rank == 0 else arr[:0]))
            for k, v in attrs.items():
                f.attrs[k] = v
        return
    parts = {name: comm.gather(arr, root=0) for name, arr in data.items()}
    if comm.rank == 0:
        with h5py.File(path, "w", **options) as f:
            grp = f.create_group("particles")
            for name, blocks in parts.items():
                arr = np.concatenate(blocks)
                grp.create_dataset(name, data=arr, **_checksummed(arr.shape, arr.dtype))
            for name, arr in extra.items():
                f.create_dataset(name, data=arr, **_checksummed(arr.shape, arr.dtype))
            for k, v in attrs.items():
                f.attrs[k] = v


class SnapshotWriter:
    """Writes snapshots into `out_dir` and keeps the XDMF index current. Collective `write`."""

    def __init__(self, comm, out_dir, domain, run=None, scene=None):
        self.comm = comm
        self.out_dir = Path(out_dir)
        self.domain = domain
        self.run = run  # the run's id, stamped on every snapshot (a continuation in place checks it)
        # the scene as a JSON table, on every snapshot too: psph plot reads a run in progress with it
        self.scene = scene
        self.entries = []  # (file name, time, step, {field: (shape tail, dtype)})

    def checkpoint_state(self) -> list:
        """The snapshot index, JSON-able (for checkpoints)."""
        return [[name, t, step, total, {n: [list(tail), np.dtype(dt).str] for n, (tail, dt) in meta.items()}]
                for name, t, step, total, meta in self.entries]

    def restore(self, entries) -> None:
        """Continue the index from a checkpoint's and rewrite the XDMF (rank 0) if this directory holds any of
        its snapshots: snapshots written after the checkpoint are dropped from it (their files are written
        again as the run reaches them), and so are the checkpoint's that are not in this directory (a restart
        into another --out). Collective."""
        self.entries = [(name, t, step, total, {n: (tuple(tail), np.dtype(dt)) for n, (tail, dt) in meta.items()})
                        for name, t, step, total, meta in entries]
        on_root(self.comm, lambda: self._write_index() if self._present() or (self.out_dir / XDMF_NAME).exists()
                else None)

    def _present(self) -> list:
        """The index's entries whose files are in the output directory."""
        return [e for e in self.entries if (self.out_dir / e[0]).is_file()]

    def _write_index(self) -> None:
        write_text_atomic(self.out_dir / XDMF_NAME, xdmf_document(self._present(), self.domain.dim))

    def write(self, particles, step: int, time: float, extra=None, names=None, exclude=("row",)) -> Path:
        """Write owned particles' fields (all but `exclude` and the scratch fields, or `names`) plus `extra` owned
        arrays. Collective."""
        if names is None:
            names = [n for n in particles.names if n not in exclude and not particles.specs[n].scratch]
        data = {n: particles.owned(n) for n in names}
        data["position"] = data["position"].copy()
        self.domain.wrap(data["position"])
        for name, arr in (extra or {}).items():
            data[name] = np.asarray(arr)
        start, total, ordered = to_gid_blocks(self.comm, particles.owned("gid"), data)
        if particles.dim == 1:
            ordered["position_xyz"] = np.concatenate(
                [ordered["position"], np.zeros((len(ordered["position"]), 2))], axis=1)
        name = snapshot_name(len(self.entries))
        path = self.out_dir / name
        tmp = path.with_name(name + ".tmp")
        attrs = {"time": float(time), "step": int(step)} | ({"run": self.run} if self.run else {}) \
            | ({"scene": self.scene} if self.scene else {})
        try:
            write_particle_file(self.comm, str(tmp), start, total, ordered, attrs)
        except BaseException:
            if self.comm.rank == 0:
                tmp.unlink(missing_ok=True)
            raise
        self.comm.Barrier()
        meta = {n: (a.shape[1:], a.dtype) for n, a in ordered.items()}
        self.entries.append((name, float(time), int(step), total, meta))

        def publish():
            try:
                replace_atomically(tmp, path)
            except BaseException:  # (a review: a failed publish left snapshot_NNNNNN.h5.tmp in OUT)
                tmp.unlink(missing_ok=True)
                raise
            self._write_index()

        on_root(self.comm, publish)  # (its failure is every rank's: a style audit found the others in a Barrier)
        return path


def _number_type(dtype) -> tuple:
    dtype = np.dtype(dtype)
    if dtype.kind == "f":
        return "Float", dtype.itemsize
    if dtype.kind in "iu":
        if dtype.itemsize == 1:
            return ("Char" if dtype.kind == "i" else "UChar"), 1
        return ("Int" if dtype.kind == "i" else "UInt"), dtype.itemsize
    return None


def _data_item(file, dataset, dims, dtype) -> str:
    number, precision = _number_type(dtype)
    shape = " ".join(str(d) for d in dims)
    return (f'<DataItem Dimensions="{shape}" NumberType="{number}" Precision="{precision}" Format="HDF">'
            f"{file}:/particles/{dataset}</DataItem>")


def xdmf_document(entries, dim: int) -> str:
    """XDMF 2 temporal collection of Polyvertex grids, one per snapshot (scalars and vectors)."""
    grids = []
    for file, time, step, total, meta in entries:
        if dim == 1:
            geom = ('<Geometry GeometryType="XYZ">'
                    + _data_item(file, "position_xyz", (total, 3), np.float64) + "</Geometry>")
        else:
            geom = (f'<Geometry GeometryType="{"XY" if dim == 2 else "XYZ"}">'
                    + _data_item(file, "position", (total, dim), np.float64) + "</Geometry>")
        attrs = []
        for name, (tail, dtype) in meta.items():
            if name in ("position", "position_xyz") or _number_type(dtype) is None:
                continue
            if tail == () or tail == (1,) == (dim,):  # a 1-D run's vectors (velocity) are scalars to ParaView
                kind = "Scalar"
            elif tail == (dim,):
                kind = "Vector"
            else:
                continue  # tensors stay in the HDF5 file only
            attrs.append(f'<Attribute Name="{name}" AttributeType="{kind}" Center="Node">'
                         + _data_item(file, name, (total,) + tuple(tail), dtype) + "</Attribute>")
        grids.append(
            f'<Grid Name="step_{step}" GridType="Uniform"><Time Value="{time!r}"/>'
            f'<Topology TopologyType="Polyvertex" NumberOfElements="{total}" NodesPerElement="1"/>'
            + geom + "".join(attrs) + "</Grid>")
    return ('<?xml version="1.0" ?>\n<Xdmf Version="2.0"><Domain>'
            '<Grid Name="particles" GridType="Collection" CollectionType="Temporal">\n'
            + "\n".join(grids) + "\n</Grid></Domain></Xdmf>\n")
