"""history.csv: fixed columns, except after a restart from a checkpoint written by an older psph."""

import pytest
from mpi4py import MPI

from psph.io.history import History, read_history


def test_columns_are_fixed_by_the_first_row(tmp_path):
    h = History(MPI.COMM_SELF, tmp_path)
    h.append({"time": 0.0, "a": 1.0})
    with pytest.raises(KeyError, match=r"\['b'\] not in the first row"):
        h.append({"time": 1.0, "a": 2.0, "b": 3.0})


def test_a_restart_from_an_older_checkpoint_adds_the_new_columns(tmp_path):
    """An older checkpoint's rows lack a column this psph writes (the bodies' cm_* columns, say): the restart
    continues, and the old rows get empty cells there."""
    h = History(MPI.COMM_SELF, tmp_path)
    h.restore([{"time": 0.0, "a": 1.0}, {"time": 1.0, "a": 2.0}])
    h.append({"time": 2.0, "a": 3.0, "b": 4.0}, flush=True)
    rows = read_history(tmp_path / "history.csv")
    assert [r["a"] for r in rows] == [1.0, 2.0, 3.0] and [r["b"] for r in rows] == [None, None, 4.0]


def test_a_checkpoint_written_after_such_a_restart_restores(tmp_path):
    """The checkpoint written after that restart holds both kinds of rows; restarting from it keeps them."""
    h = History(MPI.COMM_SELF, tmp_path)
    h.restore([{"time": 0.0, "a": 1.0}, {"time": 1.0, "a": 2.0, "b": 4.0}])
    h.append({"time": 2.0, "a": 3.0, "b": 5.0}, flush=True)
    rows = read_history(tmp_path / "history.csv")
    assert [r["b"] for r in rows] == [None, 4.0, 5.0]


def test_a_series_restarted_keeps_its_good_rows_and_sets_another_layout_aside(tmp_path):
    """An I/O audit: a torn last line (a kill or a full disk mid-write) crashed a restart on rank 0 alone, or
    stayed in the file; a restart that changed output.probes kept the old rows under the new header."""
    from psph.io.history import start_series

    path = tmp_path / "probes.csv"
    path.write_text("time,p_0,u_0\n0.1,1.0,2.0\n0.2,nan,nan\n0.3,1.5,2.5\n\n0.4\n0.35,1.0,x\n")
    said = start_series(path, "time,p_0,u_0", resumed_at=0.25)
    assert path.read_text() == "time,p_0,u_0\n0.1,1.0,2.0\n0.2,nan,nan\n" and "dropped 3 damaged row(s)" in said
    said = start_series(path, "time,p_0,u_0,p_1,u_1", resumed_at=0.15)
    assert path.read_text() == "time,p_0,u_0,p_1,u_1\n"
    aside = tmp_path / "probes_upto_t0.15.csv"
    assert aside.read_text() == "time,p_0,u_0\n0.1,1.0,2.0\n" and aside.name in said
    path.write_text(path.read_text() + "0.1,1,2,3,4\n0.2,1,2,3,4\n")  # a second restart there, other probes again
    said = start_series(path, "time,p_0", resumed_at=0.15)
    assert "probes_upto_t0.15_2.csv" in said and aside.read_text() == "time,p_0,u_0\n0.1,1.0,2.0\n"
    assert (tmp_path / "probes_upto_t0.15_2.csv").read_text() == "time,p_0,u_0,p_1,u_1\n0.1,1,2,3,4\n"
    assert start_series(path, "time,p_0,u_0,p_1,u_1") == "" and path.read_text() == "time,p_0,u_0,p_1,u_1\n"


def test_a_particle_file_the_disk_cannot_hold_is_refused_before_it_is_written(tmp_path, monkeypatch):
    """An I/O audit: a full disk during a checkpoint hung a 2-rank run in HDF5's collective close, and on one
    rank h5py's ValueError went out as an internal error with a segfault. The space is checked first, on every
    rank alike, and the error is an OSError (psph run: one line, exit 1); no partial file is left."""
    import os
    from types import SimpleNamespace

    import numpy as np

    from psph.io.snapshots import write_particle_file

    data = {"position": np.zeros((1000, 2))}
    full = SimpleNamespace(f_blocks=10**6, f_bavail=10, f_bfree=10, f_frsize=4096)  # (root may use f_bfree)
    monkeypatch.setattr(os, "statvfs", lambda path: full)
    with pytest.raises(OSError, match=r"No space left on device: .*a.h5 needs about 0.1 MiB, 0.0 MiB are free"):
        write_particle_file(MPI.COMM_SELF, str(tmp_path / "a.h5"), 0, 1000, data, {})
    assert not list(tmp_path.iterdir())
    monkeypatch.setattr(os, "statvfs", lambda path: SimpleNamespace(f_blocks=10**6, f_bavail=10**6, f_bfree=10**6,
                                                                    f_frsize=4096))
    write_particle_file(MPI.COMM_SELF, str(tmp_path / "a.h5"), 0, 1000, data, {})
    assert (tmp_path / "a.h5").stat().st_size > 16000
    # a file system that counts no blocks (an unlimited tmpfs) says nothing of its space: written (a review)
    monkeypatch.setattr(os, "statvfs", lambda path: SimpleNamespace(f_blocks=0, f_bavail=0, f_bfree=0, f_frsize=4096))
    write_particle_file(MPI.COMM_SELF, str(tmp_path / "b.h5"), 0, 1000, data, {})
    assert (tmp_path / "b.h5").stat().st_size > 16000


def test_a_summary_with_non_finite_values_is_strict_json(tmp_path):
    """JSON has no NaN or Infinity: summary.json's smallest spacing after the fluid left (inf) and an error
    against a zero reference (nan) are written as null, which every JSON reader takes (a diagnostics audit:
    JavaScript's JSON.parse refused the file)."""
    import json

    import numpy as np

    from psph.io.files import write_json_atomic

    write_json_atomic(tmp_path / "s.json", {"final": {"min_spacing": float("inf"), "error": np.float64("nan"),
                                                       "mass": np.float64(1.5), "steps": np.int64(3)},
                                            "norms": [1.0, float("-inf")], "field": np.array([np.nan, 2.0])})

    def refuse(constant):
        raise ValueError(constant)

    data = json.loads((tmp_path / "s.json").read_text(), parse_constant=refuse)
    assert data == {"final": {"min_spacing": None, "error": None, "mass": 1.5, "steps": 3}, "norms": [1.0, None],
                    "field": [None, 2.0]}


@pytest.mark.parametrize("name,holds", [("probes.csv", True), ("packing.csv", True), ("wall_pressure.csv", True),
                                        ("checkpoint_000012.h5", True), ("psph.log", False), ("notes.txt", False)])
def test_any_of_psphs_outputs_but_the_log_marks_a_directory_as_holding_results(tmp_path, name, holds):
    """A run must not overwrite results without --overwrite: probes.csv alone was overwritten (a fuzzing audit:
    only summary.json, history.csv, psph.xdmf, snapshots and checkpoints were looked for)."""
    from psph.io.files import holds_results

    (tmp_path / name).write_text("x")
    assert holds_results(tmp_path) is holds
