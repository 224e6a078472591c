"""Snapshots: gid order on any rank count, complete files only, an XDMF series VTK/ParaView reads."""

import h5py
import numpy as np
import pytest
from mpi4py import MPI

from psph.io.history import History, read_history
from psph.io.snapshots import XDMF_NAME, SnapshotWriter, snapshot_files
from psph.simulation import build_system
from tests.conftest import periodic_scene

pytestmark = pytest.mark.mpi


def write_series(comm, out, scene, times):
    system = build_system(scene, comm)
    writer = SnapshotWriter(comm, out, system.domain)
    p = system.particles
    for t in times:
        p.owned("position")[:, 0] += 0.01  # moves; positions are written wrapped into the box
        writer.write(p, step=int(100 * t), time=t, extra={"marker": p.owned("gid") * 2.0,
                                                          "shift": p.owned("position") + 1.0})
    return system


def test_snapshots_are_in_gid_order_and_rank_independent(comm, mpi_tmp_path):
    scene = periodic_scene(dim=2, n=16, sigma=0.2)
    write_series(comm, mpi_tmp_path, scene, [0.0, 0.5])
    serial_dir = mpi_tmp_path / f"serial_{comm.rank}"
    serial_dir.mkdir()
    write_series(MPI.COMM_SELF, serial_dir, scene, [0.0, 0.5])
    comm.Barrier()
    for name in ("snapshot_000000.h5", "snapshot_000001.h5"):
        with h5py.File(mpi_tmp_path / name, "r") as par, h5py.File(serial_dir / name, "r") as ser:
            assert np.array_equal(par["particles/gid"][:], np.arange(256))
            assert np.array_equal(par["particles/marker"][:], 2.0 * np.arange(256))
            for field in ("position", "kind", "volume"):
                assert np.array_equal(par[f"particles/{field}"][:], ser[f"particles/{field}"][:]), field
            assert np.all((par["particles/position"][:] >= 0.0) & (par["particles/position"][:] < 1.0))
            assert par.attrs["time"] == ser.attrs["time"]
    assert not list(mpi_tmp_path.glob("*.tmp"))


def test_xdmf_series_opens_in_vtk(comm, mpi_tmp_path):
    """ParaView's Xdmf reader (VTK's vtkXdmfReader) sees every time step, the positions and fields."""
    scene = periodic_scene(dim=2, n=10)
    write_series(comm, mpi_tmp_path, scene, [0.0, 0.25, 0.5])
    comm.Barrier()
    if comm.rank != 0:
        return
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXdmf2 import vtkXdmfReader

    reader = vtkXdmfReader()
    reader.SetFileName(str(mpi_tmp_path / XDMF_NAME))
    reader.UpdateInformation()
    info = reader.GetOutputInformation(0)
    from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as sddp

    assert list(info.Get(sddp.TIME_STEPS())) == [0.0, 0.25, 0.5]
    reader.UpdateTimeStep(0.5)
    grid = reader.GetOutputDataObject(0)
    assert grid.GetNumberOfPoints() == 100
    with h5py.File(mpi_tmp_path / "snapshot_000002.h5", "r") as f:
        assert np.allclose(vtk_to_numpy(grid.GetPoints().GetData())[:, :2], f["particles/position"][:])
    names = {grid.GetPointData().GetArrayName(k) for k in range(grid.GetPointData().GetNumberOfArrays())}
    assert {"gid", "kind", "volume", "marker"} <= names


def test_one_dimensional_series_has_a_geometry_and_its_vectors(comm, mpi_tmp_path):
    """A 1-D series: its positions, and its vectors (a velocity, here `shift`, of one component: they were
    left out of the XDMF, an audit) as scalars."""
    write_series(comm, mpi_tmp_path, periodic_scene(dim=1, n=40), [0.0])
    comm.Barrier()
    if comm.rank == 0:
        from vtkmodules.util.numpy_support import vtk_to_numpy
        from vtkmodules.vtkIOXdmf2 import vtkXdmfReader

        reader = vtkXdmfReader()
        reader.SetFileName(str(mpi_tmp_path / XDMF_NAME))
        reader.Update()
        grid = reader.GetOutputDataObject(0)
        assert grid.GetNumberOfPoints() == 40
        with h5py.File(mpi_tmp_path / "snapshot_000000.h5", "r") as f:
            assert np.array_equal(vtk_to_numpy(grid.GetPointData().GetArray("shift")), f["particles/shift"][:, 0])


def test_history_rewrites_atomically(comm, mpi_tmp_path):
    h = History(comm, mpi_tmp_path, interval=3600.0)
    h.append({"time": 0.0, "a": 1.0})  # the first row is written at once
    h.append({"time": 0.1, "a": float("nan")})  # later ones wait for the interval or a flush
    with pytest.raises(KeyError):
        h.append({"time": 0.2, "new_column": 1.0})
    comm.Barrier()
    assert len(read_history(mpi_tmp_path / "history.csv")) == 1
    comm.Barrier()
    h.flush()
    comm.Barrier()
    rows = read_history(mpi_tmp_path / "history.csv")
    assert [r["time"] for r in rows] == [0.0, 0.1] and rows[0]["a"] == 1.0 and np.isnan(rows[1]["a"])
    assert not list(mpi_tmp_path.glob("*.tmp"))



def test_snapshot_files_are_listed_in_the_order_written(tmp_path):
    """By index, not by name (snapshot_1000000.h5 sorted before snapshot_999999.h5), without a file being
    written (.tmp) or another name."""
    for name in ("snapshot_1000000.h5", "snapshot_999999.h5", "snapshot_000003.h5", "snapshot_000004.h5.tmp",
                 "snapshot_x.h5", "checkpoint_000005.h5"):
        (tmp_path / name).write_bytes(b"")
    assert [p.name for p in snapshot_files(tmp_path)] == ["snapshot_000003.h5", "snapshot_999999.h5",
                                                         "snapshot_1000000.h5"]


def test_an_output_directory_rank_0_cannot_make_stops_every_rank(comm, mpi_tmp_path):
    """Rank 0 makes the output directory, writes the XDMF index and publishes snapshots and checkpoints; a
    failure there (a file where the directory should be) was rank 0's alone, and the others waited in the
    Barrier after it for ever: a library user's driver hung (a style audit). Now every rank raises."""
    from psph.drivers.fluid import FluidDriver

    blocker = mpi_tmp_path / "a_file"
    if comm.rank == 0:
        blocker.write_text("not a directory")
    comm.Barrier()
    scene = periodic_scene(n=8, physics={"scheme": "delta_ale"}, time={"t_end": 0.01})
    with pytest.raises(OSError, match="a_file") as info:  # rank 0's error, of its type, on every rank
        FluidDriver(scene, comm, blocker / "out")
    assert comm.allgather(type(info.value).__name__) == [type(info.value).__name__] * comm.size
    assert comm.allgather(comm.rank) == list(range(comm.size))  # every rank got here, none is still inside
