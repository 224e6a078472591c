"""Restarts and output directories that must refuse, in one line, before any work: a checkpoint holding a
non-finite value or an inconsistent state, an end time not after the checkpoint's, a new run over a
checkpoint, a log that cannot be written; a continuation in place replaces a finished run's results only
with --overwrite and leaves its directory one consistent run whatever happens; a restart into another
directory indexes only the snapshots it holds."""

import json
import re
import shutil

import h5py
import numpy as np
import pytest
from mpi4py import MPI

from psph.errors import UsageError
from psph.io.checkpoint import latest_checkpoint, read_checkpoint, seal
from psph.io.history import read_history
from psph.scene.load import read_table, scene_from_table
from psph.scene.validate import to_table
from tests.conftest import periodic_scene
from tests.helpers import CASES, run_psph
from tests.io.test_checkpoint import same_history

# cases/taylor_green.toml cut short: 100 particles, 14 steps to t = 0.05 (a history row each), snapshots at 0,
# 0.025 and the end, checkpoints at steps 5 and 10 (10 kept)
SCENE = """
name = "tg"
[domain]
dimension = 2
lower = [0.0, 0.0]
upper = [1.0, 1.0]
periodic = [true, true]
dx = 0.1
h_over_dx = 2.0
kernel = "wendland_c6"
[initial]
velocity = "taylor_green"
[physics]
scheme = "delta_ale"
reynolds = 100.0
sound_speed = 10.0
[shifting]
method = "none"
[time]
t_end = 0.05
[output]
every = 0.025
checkpoint_every = 5
"""
CHECKPOINT = "checkpoint_000010.h5"


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "tg.toml"
    path.write_text(SCENE)
    return path


@pytest.fixture(scope="module")
def finished(tmp_path_factory, scene_file):
    """A finished coarse Taylor-Green run (never modified: tests copy it)."""
    out = tmp_path_factory.mktemp("finished") / "run"
    done = run_psph("run", scene_file, "--out", out, "--quiet")
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in out.glob("*.h5")) == [CHECKPOINT] + [f"snapshot_00000{k}.h5" for k in range(3)]
    return out


def copy_run(finished, where):
    shutil.copytree(finished, where)
    return where


def contents(directory) -> dict:
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir()) if p.is_file()}


def one_line_error(done, code=2) -> str:
    assert done.returncode == code, done.stdout + done.stderr
    assert "Traceback" not in done.stderr + done.stdout
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("psph: error: "), done.stderr
    return lines[0]


def edit_checkpoint(source, target, edit):
    """A copy of the checkpoint `source`, edited and sealed again: as if written so (the checks of its
    contents, not the seal's)."""
    shutil.copy(source, target)
    with h5py.File(target, "r+") as f:
        edit(f)
    seal(target)
    return target


def set_dataset(f, name, value):
    del f[name]
    f[name] = value


def edit_state(edit):
    def change(f):
        state = json.loads(bytes(f["state"][()]).decode())
        edit(state)
        set_dataset(f, "state", np.frombuffer(json.dumps(state).encode(), dtype=np.uint8))
    return change


def xdmf_files(directory) -> list:
    return sorted(set(re.findall(r"(snapshot_\d+\.h5):", (directory / "psph.xdmf").read_text())))


# ------------------------------------------------------------------ A, D: what a checkpoint must hold
@pytest.mark.parametrize("ranks", [1, 2])
def test_a_checkpoint_holding_a_nan_position_is_refused_on_every_rank(finished, tmp_path, ranks):
    """A NaN position would stall the neighbour search for ever: refused before any work, on every rank
    (here the row is rank 1's of two)."""
    def nan_position(f):
        pos = f["particles/position"][()]
        pos[-1, 0] = np.nan
        f["particles/position"][...] = pos

    bad = edit_checkpoint(finished / CHECKPOINT, tmp_path / "nan.h5", nan_position)
    done = run_psph("run", "--restart", bad, "--out", tmp_path / "out", ranks=ranks, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    line = done.stderr.splitlines()[0]  # mpiexec adds its own lines about the exit code
    assert line == (f"psph: error: cannot restart from {str(bad)!r}: particles/position holds a non-finite value "
                    "(nan in row 99)")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("ranks", [1, 2])
def test_a_repeated_gid_is_refused_on_every_rank(finished, tmp_path, ranks):
    """Rank 0 alone reads the whole gid column; the refusal reaches every rank (the copy is in rank 1's rows
    of two)."""
    bad = edit_checkpoint(finished / CHECKPOINT, tmp_path / "gid.h5",
                          lambda f: f["particles/gid"].write_direct(f["particles/gid"][:1], dest_sel=np.s_[99:100]))
    done = run_psph("run", "--restart", bad, "--out", tmp_path / "out", ranks=ranks, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.splitlines()[0] == f"psph: error: cannot restart from {str(bad)!r}: particles/gid repeats gid 0"
    assert not (tmp_path / "out").exists()


def test_a_checkpoint_holding_an_infinite_value_in_any_field_is_refused(finished, tmp_path):
    def inf_density(f):
        rho = f["particles/density"][()]
        rho[3] = np.inf
        f["particles/density"][...] = rho

    bad = edit_checkpoint(finished / CHECKPOINT, tmp_path / "inf.h5", inf_density)
    with pytest.raises(UsageError, match=r"particles/density holds a non-finite value \(inf in row 3\)"):
        read_checkpoint(MPI.COMM_SELF, bad)


@pytest.mark.parametrize("edit,words", [
    (edit_state(lambda s: s.pop("history")), "its state lacks 'history'"),
    (edit_state(lambda s: s["driver"].pop("totals")), "its state's 'driver' lacks 'totals'"),
    (edit_state(lambda s: s.update(time="soon")), "its state's 'time' is not a finite number"),
    (edit_state(lambda s: s.update(run=5)), "its state's 'run' is not a run id"),
    (lambda f: set_dataset(f, "particles/position", f["particles/position"][:-3]),
     "particles/position has shape (97, 2), expected (100, 2)"),
    (lambda f: set_dataset(f, "particles/velocity", f["particles/velocity"][:, :1]),
     "particles/velocity has shape (100, 1), expected (100, 2)"),
    (lambda f: set_dataset(f, "particles/gid", f["particles/gid"][()].astype(np.float64)),
     "particles/gid holds float64, expected int64"),
    (lambda f: f["particles"].pop("mass"), "it has no dataset particles/mass"),
    (lambda f: f["particles/gid"].write_direct(f["particles/gid"][:1], dest_sel=np.s_[1:2]),
     "particles/gid repeats gid 0"),
    (lambda f: f["particles/kind"].write_direct(np.array([77], np.int8), dest_sel=np.s_[4:5]),
     "particles/kind holds 77, which is no particle kind"),
    (lambda f: f["particles/volume"].write_direct(np.array([-1.0]), dest_sel=np.s_[4:5]),
     "particles/volume holds -1 in row 4, not > 0"),
    (lambda f: f["particles/density"].write_direct(np.array([0.0]), dest_sel=np.s_[7:8]),
     "particles/density holds 0 in row 7, not > 0"),
])
def test_an_inconsistent_checkpoint_is_one_line_naming_what_is_wrong(finished, tmp_path, edit, words):
    bad = edit_checkpoint(finished / CHECKPOINT, tmp_path / "bad.h5", edit)
    with pytest.raises(UsageError) as err:
        read_checkpoint(MPI.COMM_SELF, bad)
    assert str(err.value) == f"cannot restart from {str(bad)!r}: {words}"


def test_a_checkpoint_with_damaged_metadata_is_one_line(finished, tmp_path):
    """HDF5 metadata overwritten by 256 random bytes (a damaged disk or copy): h5py raises RuntimeError
    ("bad local heap signature" and the like), which was a traceback called a bug."""
    bad = tmp_path / "damaged.h5"
    shutil.copy(finished / CHECKPOINT, bad)
    with open(bad, "r+b") as f:
        f.seek(600)
        f.write(np.random.default_rng(7).bytes(256))
    with pytest.raises(UsageError, match=rf"^cannot restart from {re.escape(repr(str(bad)))}: "):
        read_checkpoint(MPI.COMM_SELF, bad)


def flip_a_bit(path, dataset, row):
    """Flip one bit of `dataset`'s stored bytes in the chunk holding `row` (a disk or copy error that leaves
    the file's structure whole: the values read back would be plausible and wrong)."""
    with h5py.File(path, "r") as f:
        ds = f[dataset]
        chunk = ds.id.get_chunk_info_by_coord((row - row % ds.chunks[0],) + (0,) * (ds.ndim - 1))
        at = f.userblock_size + chunk.byte_offset + 5  # (HDF5's offsets start after the user block)
    with open(path, "r+b") as raw:
        raw.seek(at)
        byte = raw.read(1)[0]
        raw.seek(at)
        raw.write(bytes([byte ^ 0x04]))


@pytest.mark.parametrize("ranks", [1, 2])
@pytest.mark.parametrize("dataset,what", [("particles/position", "particles/position"),
                                          ("particles/gid", "particles/gid"), ("state", "its state")])
@pytest.mark.parametrize("resealed", [False, True])
def test_a_checkpoint_damaged_within_a_dataset_is_refused(finished, tmp_path, ranks, dataset, what, resealed):
    """One flipped bit in the stored values (which the checks of structure, finiteness and range need not
    see) fails the file's CRC32 seal, checked before HDF5 reads it; sealed again (a bit flipped before the
    seal was computed), every dataset's Fletcher32 checksum still refuses it, naming the dataset, on every
    rank (the position's damaged rows are rank 0's of two)."""
    bad = tmp_path / "flipped.h5"
    shutil.copy(finished / CHECKPOINT, bad)
    flip_a_bit(bad, dataset, 0)
    if resealed:
        seal(bad)
    done = run_psph("run", "--restart", bad, "--out", tmp_path / "out", ranks=ranks, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.splitlines()[0] == f"psph: error: cannot restart from {str(bad)!r}: " + (
        f"{what} is damaged: its Fletcher32 checksum fails" if resealed else
        "it is damaged: its bytes differ from those written (the CRC32 of the file fails)")
    assert not (tmp_path / "out").exists()


def test_every_dataset_of_a_snapshot_and_a_checkpoint_is_checksummed(finished):
    def datasets(f):
        found = []
        f.visititems(lambda name, obj: found.append((name, obj.fletcher32)) if isinstance(obj, h5py.Dataset) else None)
        return found

    names = []
    for path in sorted(finished.glob("*.h5")):
        with h5py.File(path, "r") as f:
            names += [(path.name, name, checked) for name, checked in datasets(f)]
    assert len(names) > 20 and {n[0] for n in names} == {p.name for p in finished.glob("*.h5")}
    assert [n[:2] for n in names if not n[2]] == []


def test_a_truncated_or_unsealed_checkpoint(finished, tmp_path):
    """A copy cut short is refused by the seal's length; a seal overwritten is refused; a checkpoint of an
    older psph, without a seal (its HDF5 signature at byte 0), is still read."""
    data = (finished / CHECKPOINT).read_bytes()
    cut = tmp_path / "cut.h5"
    cut.write_bytes(data[:-1])
    with pytest.raises(UsageError, match="the CRC32 of the file fails"):
        read_checkpoint(MPI.COMM_SELF, cut)
    cut.write_bytes(b"x" * 16 + data[16:])
    with pytest.raises(UsageError, match="its first block is damaged or it is not a psph checkpoint"):
        read_checkpoint(MPI.COMM_SELF, cut)
    state, particles, _ = read_checkpoint(MPI.COMM_SELF, finished / CHECKPOINT)
    old = tmp_path / "old.h5"
    with h5py.File(old, "w", libver="latest") as f:  # the same contents, written without a user block
        with h5py.File(finished / CHECKPOINT, "r") as g:
            for name in g.attrs:
                f.attrs[name] = g.attrs[name]
            for name in ("particles", "state"):
                g.copy(name, f)
    assert old.read_bytes()[:8] == b"\x89HDF\r\n\x1a\n"
    again, read, _ = read_checkpoint(MPI.COMM_SELF, old)
    assert again == state and np.array_equal(read.owned("position"), particles.owned("position"))


@pytest.mark.parametrize("case,expected", [("dam_break.toml", True), ("taylor_green.toml", False)])
def test_a_checkpoint_older_than_wall_adhesion_keeps_the_walls_it_ran_with(finished, tmp_path, case, expected):
    """A checkpoint's scene lists every key of its day: one written before physics.wall_adhesion has none,
    and the key's default (false) would change the walls mid-run. read_checkpoint gives it true where the
    key applies (clone walls and a free surface) and leaves a new checkpoint's value as it is."""
    table = to_table(scene_from_table(read_table(CASES / case)))
    del table["physics"]["wall_adhesion"]
    old = edit_checkpoint(finished / CHECKPOINT, tmp_path / "old.h5", edit_state(lambda s: s.update(scene=table)))
    assert scene_from_table(read_checkpoint(MPI.COMM_SELF, old)[0]["scene"]).physics.wall_adhesion is expected
    table["physics"]["wall_adhesion"] = False
    new = edit_checkpoint(finished / CHECKPOINT, tmp_path / "new.h5", edit_state(lambda s: s.update(scene=table)))
    assert read_checkpoint(MPI.COMM_SELF, new)[0]["scene"]["physics"]["wall_adhesion"] is False


@pytest.mark.parametrize("diffusion,expected", [(None, 0.4), (0.3, 0.3)])
def test_a_checkpoint_older_than_lind_diffusion_keeps_the_coefficient_it_ran_with(finished, tmp_path, diffusion,
                                                                                 expected):
    """Lind's law took shifting.diffusion (0.4 h^2 by default) before shifting.lind_diffusion (0.2): a
    checkpoint of that day, whose scene lists no lind_diffusion, continues with the coefficient it ran with
    (a review: it went on at 0.2, and a restart cannot change shifting keys)."""
    table = to_table(scene_from_table(read_table(CASES / "taylor_green.toml")))
    table["shifting"].update(method="lind")
    table["iips"].update(update="none")
    del table["shifting"]["lind_diffusion"]
    if diffusion is None:
        del table["shifting"]["diffusion"]
    else:
        table["shifting"]["diffusion"] = diffusion
    old = edit_checkpoint(finished / CHECKPOINT, tmp_path / "old.h5", edit_state(lambda s: s.update(scene=table)))
    assert scene_from_table(read_checkpoint(MPI.COMM_SELF, old)[0]["scene"]).shifting.lind_diffusion == expected


def test_a_checkpoint_older_than_the_extrapolated_inflow_default_keeps_a_prescribed_buffer(finished, tmp_path):
    """inflow.density defaulted to "prescribed" before 2026-11-30: a checkpoint of that day whose scene does
    not list it continues with it, not with the new default (a review); a listed value is kept."""
    table = to_table(scene_from_table(read_table(CASES / "impinging_jet.toml")))
    del table["inflow"][0]["density"]
    old = edit_checkpoint(finished / CHECKPOINT, tmp_path / "old.h5", edit_state(lambda s: s.update(scene=table)))
    assert scene_from_table(read_checkpoint(MPI.COMM_SELF, old)[0]["scene"]).inflow[0].density == "prescribed"
    table["inflow"][0]["density"] = "extrapolated"
    new = edit_checkpoint(finished / CHECKPOINT, tmp_path / "new.h5", edit_state(lambda s: s.update(scene=table)))
    assert scene_from_table(read_checkpoint(MPI.COMM_SELF, new)[0]["scene"]).inflow[0].density == "extrapolated"


def test_restart_errors_from_the_command_line_are_one_line(finished, tmp_path):
    bad = edit_checkpoint(finished / CHECKPOINT, tmp_path / "bad.h5", edit_state(lambda s: s.pop("history")))
    assert "its state lacks 'history'" in one_line_error(run_psph("run", "--restart", bad, "--out", tmp_path / "o"))
    bad = edit_checkpoint(finished / CHECKPOINT, tmp_path / "bad_scene.h5",
                          edit_state(lambda s: s["scene"]["domain"].update(dx=-1.0)))
    line = one_line_error(run_psph("run", "--restart", bad, "--out", tmp_path / "o"))
    assert line == f"psph: error: cannot restart from {str(bad)!r}: its scene: domain.dx: must be > 0.0, got -1.0"
    line = one_line_error(run_psph("run", "--restart", finished, "--out", tmp_path / "o"))  # HDF5's text: 2 lines
    assert line == (f"psph: error: cannot restart from {str(finished)!r}: a directory, not a checkpoint file (its "
                    f"latest checkpoint is {finished / CHECKPOINT})")
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------ B: an end time the run has passed
@pytest.mark.parametrize("t_end", ["0.01", "0.03650918843318125"])
def test_a_restart_ending_before_its_checkpoint_is_refused_and_touches_nothing(finished, tmp_path, t_end):
    run = copy_run(finished, tmp_path / "run")
    before = contents(run)
    line = one_line_error(run_psph("run", "--restart", run / CHECKPOINT, "--set", f"time.t_end={t_end}"))
    assert line == (f"psph: error: time.t_end: {float(t_end):g} is not after the checkpoint's time 0.0365092 "
                    "(step 10): nothing to continue")
    assert contents(run) == before


# ------------------------------------------------------------------ C: a checkpoint is a result
def test_a_new_run_does_not_remove_a_checkpoint_in_its_directory(finished, scene_file, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    shutil.copy(finished / CHECKPOINT, out / "checkpoint_000012.h5")
    line = one_line_error(run_psph("run", scene_file, "--out", out))
    assert "already holds results" in line and "--overwrite" in line
    assert contents(out) == {"checkpoint_000012.h5": (finished / CHECKPOINT).read_bytes()}


def test_a_run_replaces_only_its_own_checkpoints(tmp_path):
    """A checkpoint put into the directory while the run goes (not the run's, nor one it continues) stays;
    the run's own earlier checkpoints go once a newer one is complete."""
    from psph.drivers.fluid import FluidDriver

    scene = periodic_scene(n=10, initial={"velocity": "taylor_green"}, time={"t_end": 0.05},
                           physics={"scheme": "delta_ale", "reynolds": 100.0, "sound_speed": 10.0},
                           shifting={"method": "none"}, output={"checkpoint_every": 5})
    (tmp_path / "checkpoint_000007.h5").write_text("someone else's")
    with FluidDriver(scene, MPI.COMM_SELF, tmp_path) as driver:
        driver.run()
    assert sorted(p.name for p in tmp_path.glob("checkpoint_*")) == ["checkpoint_000007.h5", CHECKPOINT]
    assert (tmp_path / "checkpoint_000007.h5").read_text() == "someone else's"


@pytest.mark.parametrize("every,times", [(0.0, [0.1]), (0.01, [0.04, 0.05, 0.06, 0.07, 0.08, 0.09, 0.1])])
def test_a_restart_that_changes_output_every_writes_on_the_new_period(finished, tmp_path, every, times):
    """The checkpoint (t = 0.0357) was due its next snapshot at 0.05 (output.every = 0.025). A restart to
    t = 0.1 with output.every = 0 writes only the final state (it wrote one every step from 0.05 on), and with
    0.01 one at each multiple of 0.01 after the checkpoint (it started at 0.05)."""
    out = tmp_path / "elsewhere"
    done = run_psph("run", "--restart", finished / CHECKPOINT, "--out", out, "--quiet", "--set", "time.t_end=0.1",
                    "--set", f"output.every={every}")
    assert done.returncode == 0, done.stderr
    written = []
    for name in xdmf_files(out):
        with h5py.File(out / name, "r") as f:
            written.append(float(f.attrs["time"]))
    dt = 0.05 / 14
    assert len(written) == len(times) and all(0.0 <= w - t < dt for w, t in zip(written, times)), written


# ------------------------------------------------------------------ E: a restart into another directory
def test_a_restart_into_another_directory_indexes_only_its_own_snapshots(finished, tmp_path):
    """The XDMF of the new directory lists the snapshots it holds (from the checkpoint on): ParaView opens it."""
    out = tmp_path / "elsewhere"
    done = run_psph("run", "--restart", finished / CHECKPOINT, "--out", out, "--quiet")
    assert done.returncode == 0, done.stderr
    assert xdmf_files(out) == ["snapshot_000002.h5"] == sorted(p.name for p in out.glob("snapshot_*"))
    assert f"the earlier ones are in {finished}" in (out / "psph.log").read_text()
    assert xdmf_files(finished) == [f"snapshot_00000{k}.h5" for k in range(3)]
    from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as sddp
    from vtkmodules.vtkIOXdmf2 import vtkXdmfReader

    reader = vtkXdmfReader()
    reader.SetFileName(str(out / "psph.xdmf"))
    reader.Update()
    assert list(reader.GetOutputInformation(0).Get(sddp.TIME_STEPS())) == [0.05]
    assert reader.GetOutputDataObject(0).GetNumberOfPoints() == 100


# ------------------------------------------------------------------ F: continuing in place
def test_continuing_a_finished_run_in_place_needs_overwrite(finished, tmp_path):
    run = copy_run(finished, tmp_path / "run")
    before = contents(run)
    line = one_line_error(run_psph("run", "--restart", run / CHECKPOINT, "--set", "time.t_end=0.1"))
    assert line == (f"psph: error: output directory {str(run)!r} holds results past the checkpoint's t = 0.0365092 "
                    "(step 10): summary.json; continuing there replaces them: pass --overwrite to do so, or "
                    "choose another --out")
    assert contents(run) == before


def test_a_failed_continuation_in_place_leaves_one_consistent_run(finished, tmp_path):
    """Continued with --overwrite and failing at once (a skin too thin for the step: exit 3): the directory
    holds the run up to the failure, no summary of the old end, an XDMF listing exactly its snapshots."""
    run = copy_run(finished, tmp_path / "run")
    done = run_psph("run", "--restart", run / CHECKPOINT, "--set", "neighbours.skin=0.001", "--overwrite")
    assert done.returncode == 3 and "neighbours.skin" in done.stderr, done.stderr
    assert not (run / "summary.json").exists()
    snapshots = sorted(p.name for p in run.glob("snapshot_*"))
    assert xdmf_files(run) == snapshots == [f"snapshot_00000{k}.h5" for k in range(3)]
    with h5py.File(run / "snapshot_000002.h5") as f:  # the failure's state: step 11, from the checkpoint's time
        assert f.attrs["step"] == 11 and f.attrs["time"] == read_checkpoint(MPI.COMM_SELF, run / CHECKPOINT)[0]["time"]
        assert "grad_c" in f["particles"]
    assert [r["step"] for r in read_history(run / "history.csv")] == list(range(11))
    assert "removed what" in (run / "psph.log").read_text()


def test_an_interrupted_run_continues_in_place_without_overwrite(finished, tmp_path):
    """No summary: the run did not finish (killed), its snapshots past the checkpoint are written again, a
    later checkpoint's half-written temporary file is removed, and the continuation equals the run never
    interrupted."""
    run = copy_run(finished, tmp_path / "run")
    (run / "summary.json").unlink()
    (run / "checkpoint_000012.h5.tmp").write_bytes(b"half written")  # a kill during a later write: removed
    (run / "checkpoint_000007.h5.tmp").write_bytes(b"mine")  # before the checkpoint: not this continuation's
    done = run_psph("run", "--restart", run / CHECKPOINT, "--quiet")
    assert done.returncode == 0, done.stderr
    same_history(run, finished)
    assert xdmf_files(run) == xdmf_files(finished)
    assert not (run / "checkpoint_000012.h5.tmp").exists() and (run / "checkpoint_000007.h5.tmp").exists()
    for name in ("snapshot_000002.h5",):
        with h5py.File(run / name) as a, h5py.File(finished / name) as b:
            assert np.array_equal(a["particles/position"][()], b["particles/position"][()])
    assert latest_checkpoint(run).name == CHECKPOINT


def test_a_checkpoint_copied_into_another_runs_directory_does_not_continue_there(finished, scene_file, tmp_path):
    """A fuzzing audit: continuing in place trusted whatever the directory held, so a checkpoint copied beside
    another run's results took that run's snapshots for its own (listed in the XDMF, the later ones removed).
    Every snapshot, checkpoint and summary carries its run's id; a continuation keeps it, and one in place
    refuses a directory holding another run's snapshots, touching nothing."""
    other = tmp_path / "other"
    done = run_psph("run", scene_file, "--out", other, "--quiet", "--set", "output.checkpoint_every=0")
    assert done.returncode == 0, done.stderr
    (other / "summary.json").unlink()  # (an interrupted run: no summary to need --overwrite)
    shutil.copy(finished / CHECKPOINT, other / CHECKPOINT)
    before = contents(other)
    line = one_line_error(run_psph("run", "--restart", other / CHECKPOINT, "--overwrite"))
    assert line == (f"psph: error: output directory {str(other)!r} holds snapshots of another run than the "
                    "checkpoint's: snapshot_000000.h5, snapshot_000001.h5, snapshot_000002.h5; continue into "
                    "another --out")
    assert contents(other) == before
    run = read_checkpoint(MPI.COMM_SELF, finished / CHECKPOINT)[0]["run"]
    assert len(run) == 32 and json.loads((finished / "summary.json").read_text())["run"] == run
    with h5py.File(other / "snapshot_000000.h5") as f:
        assert f.attrs["run"] not in ("", run)


def test_only_readable_snapshots_stamped_by_another_run_count_as_foreign(finished, tmp_path, monkeypatch):
    """The check of a directory before a continuation in place: a snapshot of another run counts, one of this
    run or an unstamped (older psph's) one does not, and one whose metadata cannot be read (garbage, a
    truncated copy, or h5py's KeyError / RuntimeError for a broken attribute) is passed over, not raised:
    the continuation reads nothing of it."""
    from psph.io import snapshots

    run = read_checkpoint(MPI.COMM_SELF, finished / CHECKPOINT)[0]["run"]
    directory = copy_run(finished, tmp_path / "run")
    with h5py.File(directory / "snapshot_000001.h5", "r+") as f:
        f.attrs["run"] = "0" * 32
    with h5py.File(directory / "snapshot_000002.h5", "r+") as f:
        del f.attrs["run"]
    (directory / "snapshot_000003.h5").write_bytes(b"not a snapshot" * 10)
    whole = (directory / "snapshot_000000.h5").read_bytes()
    (directory / "snapshot_000004.h5").write_bytes(whole[: len(whole) // 3])
    assert snapshots.foreign_snapshots(directory, run) == [directory / "snapshot_000001.h5"]
    assert snapshots.foreign_snapshots(directory, None) == []
    for error in (KeyError, RuntimeError):
        def broken(*args, error=error, **kwargs):
            raise error("a damaged attribute")
        monkeypatch.setattr(snapshots.h5py, "File", broken)
        assert snapshots.foreign_snapshots(directory, run) == []


# ------------------------------------------------------------------ G: the log
@pytest.mark.parametrize("log,reason", [("/dev/full", "No space left on device"),
                                        ("{tmp}/nonexistent/dir/x.log", "No such file or directory")])
def test_a_log_that_cannot_be_written_is_refused_before_any_work(finished, scene_file, tmp_path, log, reason):
    log = log.format(tmp=tmp_path)
    line = one_line_error(run_psph("run", scene_file, "--out", tmp_path / "out", "--log", log))
    assert line == f"psph: error: --log {log!r}: {reason}"
    assert not (tmp_path / "out").exists()
    run = copy_run(finished, tmp_path / "run")  # --overwrite removes nothing then
    before = contents(run)
    one_line_error(run_psph("run", scene_file, "--out", run, "--log", log, "--overwrite"))
    assert contents(run) == before


@pytest.mark.parametrize("ranks", [1, 2])
def test_a_checkpoint_with_a_particle_outside_its_domain_is_refused(finished, tmp_path, ranks):
    """A finite position far outside the box (an edited or damaged file) was taken, and the restart stopped
    at its first rebuild as a numerical failure (exit 3). It is bad input, refused before any work: here the
    scene's x axis made closed (in the file's own scene) and one particle moved to x = 7."""
    def far_particle(f):
        def close_x(state):
            state["scene"]["domain"]["periodic"] = [False, True]
            state["scene"]["initial"]["velocity"] = "zero"  # Taylor-Green needs both axes periodic

        edit_state(close_x)(f)
        pos = f["particles/position"][()]
        pos[-1, 0] = 7.0
        f["particles/position"][...] = pos
        gid = int(f["particles/gid"][-1])
        f.attrs["test_gid"] = gid

    bad = edit_checkpoint(finished / CHECKPOINT, tmp_path / "far.h5", far_particle)
    with h5py.File(bad) as f:
        gid, y = int(f.attrs["test_gid"]), float(f["particles/position"][-1, 1])
    done = run_psph("run", "--restart", bad, "--out", tmp_path / "out", ranks=ranks, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.splitlines()[0] == (f"psph: error: cannot restart from {str(bad)!r}: 1 particle(s) outside "
                                           f"the scene's domain (gid {gid} at (7, {y:.6g}))")
    assert not (tmp_path / "out").exists()


def test_a_checkpoint_with_a_fluid_particle_inside_a_wall_stops_at_its_step(tmp_path):
    """A fluid particle moved 3 dx into the tank's wall (an edited file): the restart's first step mirrored it
    back into the fluid and ran on, exit 0, counting a wall reflection. The checkpoint's state is checked as
    a step's end is: the run stops at the checkpoint's step naming the particle and the wall."""
    done = run_psph("run", CASES / "hydrostatic_tank.toml", "--out", tmp_path / "run", "--quiet", "--set",
                    "domain.dx=0.1", "--set", "time.t_end=0.05", "--set", "output.checkpoint_every=5")
    assert done.returncode == 0, done.stderr

    def into_the_wall(f):
        k = int(np.flatnonzero(f["particles/kind"][()] == 0)[0])
        pos = f["particles/position"][()]
        pos[k] = [-0.3, 0.5]
        f["particles/position"][...] = pos
        f.attrs["test_gid"] = int(f["particles/gid"][k])

    bad = edit_checkpoint(latest_checkpoint(tmp_path / "run"), tmp_path / "wall.h5", into_the_wall)
    with h5py.File(bad) as f:
        gid, step = int(f.attrs["test_gid"]), int(f.attrs["step"])
    done = run_psph("run", "--restart", bad, "--set", "time.t_end=0.1", "--out", tmp_path / "out", "--quiet")
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 3 and len(lines) == 1, done.stderr
    assert lines[0].startswith(f"psph: error: a fluid particle crossed the wall of body 'tank' [step {step}, t = ")
    assert f"particle gid {gid}, at (-0.3, 0.5)]" in lines[0]


def test_a_restart_whose_override_a_moving_body_cannot_take_names_that_override(tmp_path):
    """A restarts audit: a t_end that takes the moving square into its tank's wall was refused as
    'bodies[1].motion', a key a restart cannot change; the key to change back is the override's."""
    out = tmp_path / "out"
    done = run_psph("run", CASES / "moving_square.toml", "--out", out, "--quiet", "--set", "domain.dx=0.2", "--set",
                    "time.t_end=0.05", "--set", "output.checkpoint_every=10", "--set", "shifting.method=none",
                    "--set", "iips.update=none")
    assert done.returncode == 0, done.stderr
    res = run_psph("run", "--restart", out / "checkpoint_000010.h5", "--set", "time.t_end=10", "--out",
                   tmp_path / "longer", "--quiet")
    assert res.returncode == 2 and res.stderr.startswith("psph: error: time.t_end: bodies[1].motion: 'square' "
                                                         "comes within dx of the walls of bodies[0]"), res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and not (tmp_path / "longer").exists()


def test_a_set_aside_that_fails_part_way_puts_back_what_it_moved(tmp_path, monkeypatch):
    """A review: a continuation's set-aside that failed part way (a full disk while copying history.csv) left
    the results past the checkpoint it had moved in .psph_replaced, where the next run removed them. It is
    now all or nothing; and a dangling link among the outputs is copied as the link."""
    from psph.io import files

    for name, data in (("summary.json", b"{}"), ("snapshot_000005.h5", b"later"), ("history.csv", b"t\n"),
                       ("snapshot_000001.h5", b"kept")):
        (tmp_path / name).write_bytes(data)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    later = [tmp_path / "summary.json", tmp_path / "snapshot_000005.h5"]

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(files.shutil, "copy2", full)
    with pytest.raises(OSError, match="No space left"):
        files.set_aside_for_continuation(tmp_path, later)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    monkeypatch.undo()
    (tmp_path / "probes.csv").symlink_to(tmp_path / "missing")
    aside = files.set_aside_for_continuation(tmp_path, later)
    assert sorted(p.name for p in aside.iterdir()) == ["history.csv", "probes.csv", "snapshot_000005.h5",
                                                       "summary.json"]
    files.restore_results(tmp_path, aside, clear=False)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.name != "probes.csv"} == before
