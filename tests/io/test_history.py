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
