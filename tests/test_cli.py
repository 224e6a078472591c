"""The command line: bad input gives one line and exit 2 with nothing written; runs honour the contract."""

import json
import re
import subprocess
import sys

import h5py
import numpy as np
import pytest

from tests.helpers import CASES, ROOT, mpi_environment, run_psph

SCENE = CASES / "static_perturbed.toml"


@pytest.mark.parametrize("args,words", [
    (["--set", "domain.dx=-1"], "domain.dx: must be > 0"),
    (["--set", "domain.bogus=1"], "domain.bogus: unknown key"),
    (["--set", "initial.sigma_over_dx=nan"], "initial.sigma_over_dx: must be a finite number"),
    (["--set", "shifting.method=teleport"], "shifting.method: 'teleport' is not one of"),
    (["--set", "domain.dx=1e-6"], "domain.dx: 1000000000000 particles need about"),
    (["--set", "nodot"], "expected key.path=value"),
    (["--frobnicate"], "unrecognized arguments: --frobnicate"),
])
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path, args, words):
    out = tmp_path / "out"
    res = run_psph("run", SCENE, "--out", out, *args)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("psph: error: ") and words in lines[0], res.stderr
    assert "Traceback" not in res.stderr + res.stdout
    assert not out.exists()


def test_a_body_spun_past_the_speed_of_sound_is_one_line(tmp_path):
    """Refused by key before its motion is sampled, where the speed overflowed: a numpy warning and its source
    line came before the error."""
    out = tmp_path / "out"
    res = run_psph("run", CASES / "moving_square.toml", "--out", out, "--set", "bodies.1.motion.law=constant",
                   "--set", "bodies.1.motion.angular_velocity=1e300")
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert lines[0].startswith("psph: error: bodies[1].motion.angular_velocity: ") and not out.exists()


def test_missing_scene_file(tmp_path):
    res = run_psph("run", tmp_path / "nope.toml")
    assert res.returncode == 2 and "not found" in res.stderr and "Traceback" not in res.stderr


def test_run_writes_the_output_contract(tmp_path):
    out = tmp_path / "out"
    res = run_psph("run", SCENE, "--out", out, "--set", "domain.dx=0.05", "-iips_ksp_type", "gmres")
    assert res.returncode == 0, res.stderr
    assert str(out) in res.stdout
    summary = json.loads((out / "summary.json").read_text())
    for key in ("wall_time_s", "ranks", "n_particles", "steps", "final"):
        assert key in summary
    # this run's own processes: more than the libraries' 100 MiB, less than 1 GiB
    assert 100 < summary["peak_memory_mib"] == summary["peak_memory_mib_total"] < 1024
    assert f"peak memory {summary['peak_memory_mib']:.0f} MiB per rank" in res.stdout
    assert summary["n_particles"] == 400 and summary["ranks"] == 1
    assert {"L2_grad_c", "Linf_grad_c"} <= set(summary["final"])
    header = (out / "history.csv").read_text().splitlines()[0].split(",")
    assert header[0] == "time" and "L2_grad_c" in header
    with h5py.File(out / "snapshot_000000.h5", "r") as f:
        gid = f["particles/gid"][:]
        assert np.array_equal(gid, np.arange(400))
        assert f["particles/position"].shape == (400, 2)
        assert f["particles/kind"].shape == (400,) and f["particles/grad_c"].shape == (400, 2)
        assert f.attrs["time"] == 0.0 and f.attrs["step"] == 0
    assert not list(out.glob("*.tmp"))
    # a second run does not overwrite results unless asked to
    again = run_psph("run", SCENE, "--out", out, "--set", "domain.dx=0.05")
    assert again.returncode == 2 and "already holds results" in again.stderr
    assert json.loads((out / "summary.json").read_text()) == summary
    # --overwrite removes the replaced run's files (here a longer run's later snapshot and its checkpoint,
    # which a restart would pick) and nothing else
    snapshots = sorted(out.glob("snapshot_0*.h5"))
    stale = [out / "snapshot_000007.h5", out / "checkpoint_000120.h5", out / "figures" / "history.png"]
    (out / "figures").mkdir()
    for path in stale:
        path.write_bytes(b"old")
    mine = [out / "notes.txt", out / "snapshot_best.h5"]
    for path in mine:
        path.write_text("mine")
    again = run_psph("run", SCENE, "--out", out, "--set", "domain.dx=0.05", "--overwrite")
    assert again.returncode == 0, again.stderr
    assert not any(path.exists() for path in stale) and all(path.read_text() == "mine" for path in mine)
    assert (out / "psph.log").read_text().count("running scene") == 1
    assert sorted(out.glob("snapshot_0*.h5")) == snapshots


def test_a_scene_argument_that_is_no_scene_file_says_what_it_is(tmp_path):
    """A directory or a device was "not found"; a checkpoint given as the scene was only "not UTF-8 text"."""
    snapshot = tmp_path / "s.h5"
    with h5py.File(snapshot, "w") as f:
        f["x"] = 1
    for scene, words in ((CASES, "is a directory"), ("/dev/null", "is not a regular file"),
                         (snapshot, "is not UTF-8 text (invalid start byte); to continue a run from a checkpoint: "
                                    "psph run --restart FILE")):
        res = run_psph("run", scene, "--out", tmp_path / "out")
        assert res.returncode == 2 and res.stderr.strip() == f"psph: error: scene file {str(scene)!r} {words}"
    assert not (tmp_path / "out").exists()


def test_a_scene_name_that_makes_no_directory_name_needs_out(tmp_path):
    """The default output directory ./NAME_out: name = "../x" wrote outside the working directory, "" to ./_out.
    Such a name is refused unless --out is given (a run of an older name can still be restarted or plotted), and
    so is one past the file system's 255 bytes (a fuzzing audit: an I/O failure, exit 1)."""
    for name, shown in (("../elsewhere", "'../elsewhere'"), ("a/b", "'a/b'"), ("", "''"),
                        ("a" * 300, "'" + "a" * 40 + "'...")):
        res = run_psph("run", SCENE, "--set", f'name="{name}"', "--set", "domain.dx=0.1", cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.strip() == (
            f"psph: error: name: {shown} names no output directory ./NAME_out: give --out, or a name of at most 200 "
            f"letters, digits, '.', '_' and '-' that starts with a letter or digit"), res.stderr
    assert list(tmp_path.iterdir()) == [] and not (tmp_path.parent / "elsewhere_out").exists()
    res = run_psph("run", SCENE, "--set", 'name="a b"', "--set", "domain.dx=0.1", "--out", tmp_path / "out",
                   "--quiet")
    assert res.returncode == 0, res.stderr


def test_info_lists_the_model_terms():
    res = run_psph("info", SCENE, "--set", "domain.dx=0.0125")
    assert res.returncode == 0, res.stderr
    assert "dx = 0.0125" in res.stdout
    assert "# model terms (only these run)" in res.stdout and "physics none" in res.stdout
    assert "estimated particles: 6400" in res.stdout


def test_a_reader_that_leaves_early_stops_psph_quietly(tmp_path, monkeypatch, capsys):
    """`psph info scene | head -1`: a write into a pipe whose reader has left ends psph with 128 + SIGPIPE
    and no traceback, PETSc initialised or not (its signal handler would abort the process). A broken pipe
    elsewhere (stdout still open) is a bug, reported as one."""
    import io
    import os
    import sys

    from psph import cli
    from psph.solvers.petsc import petsc

    petsc()

    read, write = os.pipe()
    os.close(read)  # the reader leaves before psph writes
    monkeypatch.setattr(sys, "stdout", io.TextIOWrapper(os.fdopen(write, "wb", buffering=0), write_through=True))
    assert cli.main(["info", str(SCENE)]) == 141
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    sys.stdout.close()

    def broken(*args):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(sys, "stdout", open(tmp_path / "stdout", "w"))
    monkeypatch.setattr(cli, "cmd_info", broken)
    monkeypatch.setitem(cli.COMMANDS, "info", broken)
    assert cli.main(["info", str(SCENE)]) == 1
    assert "internal error" in capsys.readouterr().err
    sys.stdout.close()


def test_a_run_whose_reader_left_ends_quietly(tmp_path):
    """`psph run scene | head` with the reader gone before psph writes: exit 141, no PETSc signal error."""
    import subprocess
    import sys

    from tests.helpers import ROOT, mpi_environment

    proc = subprocess.Popen([sys.executable, "-m", "psph", "run", str(SCENE), "--out", str(tmp_path / "out"),
                             "--set", "domain.dx=0.05"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
                            env=mpi_environment())
    proc.stdout.close()  # before psph has imported anything, let alone written
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 141 and b"PETSC ERROR" not in err and b"Traceback" not in err, err


def test_info_estimates_the_time_step():
    res = run_psph("info", CASES / "taylor_green.toml", "--set", "domain.dx=0.05")
    assert res.returncode == 0, res.stderr
    # cfl h / (c0 + U) = 0.2 x 0.1 / (10 + 1); nu = U L / Re = 0.01: the viscous limit (0.0666 h^2 / nu =
    # 0.0666) does not bind
    assert "estimated time step: 0.001818 (cfl h / (c0 + U)" in res.stdout and "about 550 steps" in res.stdout
    res = run_psph("info", CASES / "taylor_green.toml", "--set", "domain.dx=0.05", "--set", "physics.reynolds=0.01")
    # nu = 100: pi_ij with Wendland C6 at h/dx = 2 has lambda_max h^2 = 30.17 on the lattice; RK3 reaches
    # 2.5127 along the real axis; with the safety 0.8: 0.8 x 2.5127 / 30.17 = 0.0666 h^2 / nu = 6.66e-6
    assert "estimated time step: 6.663e-06 (viscous limit 0.0666 h^2 / nu on the lattice" in res.stdout, res.stdout


def test_info_prints_the_warnings_run_would_give(tmp_path):
    """psph info shows what psph run warns of before it starts (a CLI audit: a bare face and a low sound speed
    were told only once the run began); a scene without such settings gets no warning line."""
    sets = ["--set", "physics.sound_speed=5", "--set", "bodies=[]", "--set", "domain.dx=0.1"]
    info = run_psph("info", CASES / "dam_break.toml", *sets)
    assert info.returncode == 0, info.stderr
    warned = [line for line in info.stdout.splitlines() if line.startswith("# warning: ")]
    assert len(warned) == 2 and "physics.sound_speed = 5 is 5 times" in warned[1], info.stdout
    assert "the fluid reaches the bounded face(s) x-, y-" in warned[0], info.stdout
    run = run_psph("run", CASES / "dam_break.toml", *sets, "--set", "time.t_end=1e-9", "--set",
                   "diagnostics.dam_break=false", "--out", tmp_path, "--quiet")
    assert [line.removeprefix("psph: warning: ") for line in run.stderr.splitlines()
            if line.startswith("psph: warning: ")] == [w.removeprefix("# warning: ") for w in warned], run.stderr
    quiet = run_psph("info", CASES / "taylor_green.toml", "--set", "domain.dx=0.1")
    assert quiet.returncode == 0 and "# warning" not in quiet.stdout, quiet.stdout


@pytest.mark.parametrize("ranks,words", [("-1", "must be >= 1, got -1"), ("0", "must be >= 1, got 0"),
                                         ("two", "expected an integer, got 'two'")])
def test_info_refuses_a_rank_count_below_one(ranks, words):
    """--ranks -1 printed a negative memory estimate, and 0 was taken as 1."""
    res = run_psph("info", CASES / "taylor_green.toml", "--ranks", ranks)
    assert res.returncode == 2 and res.stderr.strip() == f"psph: error: argument --ranks: {words}", res.stderr


def test_quiet_run_logs_to_file_and_plots(tmp_path):
    runs = tmp_path / "study"
    for dx in (0.1, 0.05):
        out = runs / f"tgv_dx{dx}"
        res = run_psph("run", CASES / "taylor_green.toml", "--out", out, "--quiet", "--set", f"domain.dx={dx}",
                       "--set", "time.t_end=0.05", "--set", "output.probes=[[0.25, 0.25], [0.5, 0.5]]")
        assert res.returncode == 0 and res.stdout == "", res.stdout + res.stderr
        log = (out / "psph.log").read_text()
        assert "psph: running scene 'taylor_green'" in log and "results in" in log
    res = run_psph("plot", runs / "tgv_dx0.05")
    assert res.returncode == 0, res.stderr
    for name in ("history.png", "fields.png", "probes.png"):
        assert (runs / "tgv_dx0.05" / "figures" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    res = run_psph("plot", runs, "--figures", tmp_path / "figs")
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "figs" / "convergence.png").read_bytes()[:4] == b"\x89PNG"
    res = run_psph("plot", tmp_path / "figs")
    assert res.returncode == 2 and "holds neither a run" in res.stderr


def test_the_fields_figure_shows_grad_c_times_h_as_its_title_says(tmp_path):
    """A static run's snapshots hold grad C itself; fields.png titled it |grad C| h and showed |grad C|, 1/h
    times too high (a diagnostics audit: 2.0e-3 against the history's Linf 2.0e-4 at dx = 0.05). Its largest
    value is the history's Linf(grad C) = h max|grad C|."""
    import json

    from psph.io.history import read_history
    from psph.plot import shown_fields
    from psph.studies import last_snapshot

    out = tmp_path / "static"
    res = run_psph("run", SCENE, "--out", out, "--quiet", "--set", "domain.dx=0.05", "--set", "iips.max_newton=2")
    assert res.returncode == 0, res.stderr
    data, _ = last_snapshot(out)
    shown = shown_fields(out, data)["|grad C| h"]
    free = data["kind"] == 0
    assert shown[free].max() == pytest.approx(read_history(out / "history.csv")[-1]["Linf_grad_c"], rel=1e-9)
    assert json.loads((out / "summary.json").read_text())["scene"]["domain"]["dx"] == 0.05


def test_a_study_of_drops_is_plotted_by_their_semi_axis_error():
    from psph.plot import study_error

    assert study_error({"semi_axis_error": 4e-3, "L2_grad_c": 0.41, "L2_dfdx": None}) == "semi_axis_error"
    assert study_error({"L2_vx_error": 0.04, "L2_grad_c": 0.1}) == "L2_vx_error"
    assert study_error({"L2_grad_c": 0.1}) == "L2_grad_c" and study_error({"kinetic_energy": 1.0}) is None


def test_plot_of_a_broken_or_failed_run_is_one_line_or_leaves_out_what_is_not_finite(tmp_path):
    """A failed run's last snapshot may hold NaN (the state at the failure): fields.png leaves those particles
    out and says so. A truncated snapshot, or figures that cannot be written, are one line and exit 2."""
    out = tmp_path / "run"
    res = run_psph("run", CASES / "taylor_green.toml", "--out", out, "--quiet", "--set", "domain.dx=0.1",
                   "--set", "time.t_end=0.02")
    assert res.returncode == 0, res.stderr
    last = sorted(out.glob("snapshot_*.h5"))[-1]
    with h5py.File(last, "r+") as f:
        f["particles/position"][0] = np.nan
        f["particles/pressure"][1] = np.inf
    res = run_psph("plot", out)
    assert res.returncode == 0, res.stderr
    assert (out / "figures" / "fields.png").read_bytes()[:4] == b"\x89PNG"
    for args, words in (((), f"cannot read the last snapshot {last.name}"),
                        (("--figures", "/dev/full"), "/dev/full")):
        if not args:
            last.write_bytes(last.read_bytes()[:5000])
        res = run_psph("plot", out, *args)
        lines = res.stderr.strip().splitlines()
        assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
        assert len(lines) == 1 and lines[0].startswith("psph: error: psph plot") and words in lines[0], lines


def test_plot_names_a_damaged_summary_or_history_and_says_what_it_left_out(tmp_path):
    """A study's damaged summary.json was a JSONDecodeError traceback; a history.csv that is not numbers, or
    has no row, was passed over in silence (exit 0, nothing written and nothing said)."""
    from psph.errors import UsageError
    from psph.plot import plot

    study = tmp_path / "study"
    (study / "a").mkdir(parents=True)
    (study / "a" / "summary.json").write_text("{")
    with pytest.raises(UsageError, match=r"summary.json' is not a psph summary: Expecting"):
        plot(study)
    garbage = tmp_path / "garbage"
    garbage.mkdir()
    (garbage / "history.csv").write_text("time,step\nabc,1\n")
    with pytest.raises(UsageError, match=r"history.csv' is not a psph history: could not convert string to float"):
        plot(garbage)
    (garbage / "history.csv").write_text("")
    with pytest.raises(UsageError, match=r"^nothing to plot in .*: its history.csv holds no diagnostics and"):
        plot(garbage)
    run = tmp_path / "run"  # a run whose history lost its rows: the fields are plotted, and the history said missing
    res = run_psph("run", CASES / "taylor_green.toml", "--out", run, "--quiet", "--set", "domain.dx=0.1",
                   "--set", "time.t_end=0.01")
    assert res.returncode == 0, res.stderr
    history = run / "history.csv"
    history.write_text(history.read_text().splitlines()[0] + "\n")
    warnings = []
    assert [p.name for p in plot(run, warn=warnings.append)] == ["fields.png"]
    assert warnings == [f"{str(history)!r} holds no diagnostics (no row, or none of the columns plotted): no "
                        f"history.png"]
    (run / "summary.json").write_text("[]")  # JSON, not an object: the study's plot read it as one
    with pytest.raises(UsageError, match=r"summary.json' is not a psph summary: a JSON list, not an object"):
        plot(tmp_path)
    history.write_text("time,step\n0,1,2\n")  # a row longer than the header: DictReader gives a list
    with pytest.raises(UsageError, match=r"history.csv' is not a psph history"):
        plot(run)


def test_an_output_directory_that_cannot_be_made_is_one_line(tmp_path):
    (tmp_path / "file").write_text("mine")
    res = run_psph("run", SCENE, "--out", tmp_path / "file" / "out", "--set", "domain.dx=0.05")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("psph: error: output directory") and "Not a directory" in lines[0]
    assert (tmp_path / "file").read_text() == "mine"


def test_petsc_options_that_nothing_read_are_named_in_a_warning(tmp_path):
    """A misspelt option (-iips_ksp_rtoll) or one for a solver the scene lacks ran silently on defaults."""
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path / "a", "--quiet", "--set",
                   "domain.dx=0.1", "--set", "shifting.method=iips", "-iips_ksp_rtoll", "1e-3",
                   "-iips_ksp_type", "gmres")
    assert res.returncode == 0, res.stderr
    assert "PETSc options that nothing read: -iips_ksp_rtoll 1e-3 (misspelt" in res.stderr
    assert "gmres" not in res.stderr  # read: not named
    assert "-iips_ksp_rtoll" in (tmp_path / "a" / "psph.log").read_text()
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path / "b", "--quiet", "--set",
                   "domain.dx=0.1", "-iips_pc_type", "hypre")  # no IIPS in this scene
    assert res.returncode == 0 and "nothing read: -iips_pc_type hypre" in res.stderr, res.stderr
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path / "c", "--quiet", "--set",
                   "domain.dx=0.1", "--set", "shifting.method=iips", "--set", "iips.operator=matrix_free",
                   "-iips_mat_type", "aij")  # the matrix-free operator reads no matrix type: refused, one line
    assert res.returncode == 2 and res.stderr.strip() == ("psph: error: -iips_mat_type aij: iips.operator = "
                                                           "\"matrix_free\" builds no matrix; drop the option, or "
                                                           "use iips.operator = \"assembled\""), res.stderr
    # a run that stops says so too: the misspelling may be why (a PETSc-options audit: only a run that ended
    # well told of them)
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path / "d", "--quiet", "--set",
                   "domain.dx=0.1", "--set", "shifting.method=iips", "-iips_ksp_rtoll", "1e-3", "-iips_ksp_type",
                   "lsqr")  # LSQR breaks down with Jacobi
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 3 and lines[0].startswith("psph: error: iips linear solve diverged"), res.stderr
    assert lines[1].startswith("psph: warning: PETSc options that nothing read: -iips_ksp_rtoll 1e-3"), res.stderr


def test_what_the_machine_refuses_is_one_line_not_a_bug(tmp_path):
    """A full disk (here /dev/full as standard output) or an allocation the machine cannot give (a scene
    admitted with --allow-large) ends with one line and exit 1, not a traceback called a bug."""
    import subprocess
    import sys

    from tests.helpers import ROOT, mpi_environment

    with open("/dev/full", "w") as full:
        res = subprocess.run([sys.executable, "-m", "psph", "keys"], stdout=full, stderr=subprocess.PIPE, text=True,
                             cwd=ROOT, env=mpi_environment(), timeout=120)
    assert res.returncode == 1, res.stderr
    assert res.stderr.strip() == "psph: error: input/output failed: [Errno 28] No space left on device"
    res = run_psph("run", CASES / "taylor_green.toml", "--out", tmp_path / "big", "--quiet", "--allow-large",
                   "--set", "domain.dx=1e-6", "--set", "time.t_end=0.001")
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
    assert res.stderr.strip().startswith("psph: error: out of memory: Unable to allocate"), res.stderr


def test_a_run_of_more_steps_than_a_year_holds_is_refused_and_its_estimate_printed_short(tmp_path):
    """A failure audit: physics.reynolds = 1e-300 gave a viscous time step of 7e-304 from the first step, and
    the run went on for 77 440 steps to t = 5e-299 until stopped; psph info printed the step count with 304
    digits."""
    sets = ["--set", "physics.reynolds=1e-300", "--set", "domain.dx=0.1"]
    res = run_psph("run", CASES / "taylor_green.toml", "--out", tmp_path / "out", "--quiet", *sets)
    assert res.returncode == 2 and not (tmp_path / "out").exists(), res.stderr
    assert res.stderr.startswith("psph: error: time.t_end: 1 takes about 3") and "e+302 steps of " in res.stderr
    assert "(viscous limit " in res.stderr and "more than 1e+09 (run with --allow-large" in res.stderr
    info = run_psph("info", CASES / "taylor_green.toml", *sets)
    assert info.returncode == 0 and re.search(r"about \d\.\d+e\+302 steps to t_end = 1\n", info.stdout), info.stdout


@pytest.mark.parametrize("ranks, options, message", [
    (1, ["-iips_pc_type", "nonexistent"], "Unable to find requested PC type nonexistent"),
    (1, ["-iips_mat_type", "baij", "-iips_pc_type", "gamg"], "No method creategraph for Mat of type seqbaij"),
    (2, ["-iips_mat_type", "baij", "-iips_pc_type", "gamg"], "No method creategraph for Mat of type mpibaij"),
    # with iips.on_failure = "stop" a capped solve would stop the run (test below for "reject")
    (1, ["-iips_ksp_max_it", "1"], "max_it 1) fails on a small well-posed test system: iips linear solve diverged"),
    # stored unchecked by setFromOptions, checked when a rebuild's fresh KSP copied it: a crash mid-run
    (1, ["-iips_ksp_rtol", "1.5"], "Relative tolerance 1.5 must be non-negative and less than 1.0"),
    # an unknown type failed at the first call, after the output
    (1, ["-iips_mat_type", "nonsense"], "Unknown Mat type given: nonsense"),
    # a type outside AIJ / BAIJ got no trial solve: GAMG on SELL failed at the first call, after the output;
    # SBAIJ and IS crashed on 2 ranks, and SBAIJ solved another system on 1 (a PETSc-options audit)
    (2, ["-iips_mat_type", "sell", "-iips_pc_type", "gamg"], "No method creategraph for Mat of type mpisell"),
    (2, ["-iips_mat_type", "sbaij"], "-iips_mat_type sbaij: SBAIJ stores the upper triangle only"),
    (1, ["-iips_mat_type", "is"], "-iips_mat_type is: IS takes no values"),
    # PETSC_ERR_MISSING_FACTOR: was one rank's error, each rank printing it and aborting the job
    (2, ["-iips_pc_type", "ilu"], "Could not locate a solver type for factorization type ILU")])
def test_a_bad_iips_option_keeps_the_results_overwrite_would_replace(tmp_path, ranks, options, message):
    """--overwrite cleared the directory before the solver read its options: a misspelt preconditioner
    lost the previous run. The -iips_ options are now checked first, and the solver solves a small test
    system: GAMG, which accepts a BAIJ matrix and fails only at its first solve, is refused there."""
    out = tmp_path / "out"
    base = ["run", CASES / "static_perturbed.toml", "--out", out, "--quiet", "--set", "domain.dx=0.1", "--set",
            "shifting.method=iips"]
    assert run_psph(*base, ranks=ranks).returncode == 0
    before = sorted(p.name for p in out.iterdir())
    res = run_psph(*base, "--overwrite", *options, ranks=ranks)
    assert res.returncode == 2 and message in res.stderr, res.stderr
    assert "Traceback" not in res.stderr
    assert sorted(p.name for p in out.iterdir()) == before and (out / "summary.json").exists()


@pytest.mark.parametrize("ranks", [1, 2])
def test_bad_input_found_while_the_run_sets_up_keeps_what_overwrite_would_replace(tmp_path, ranks):
    """Input refused only while the run sets up (a fill region holding no lattice node; the kinematic
    pre-procedure leaving nothing for iips.beta to scale) came after --overwrite had deleted the previous
    run, checkpoint included (a fuzzing audit). The old results are set aside and put back, byte for byte;
    a directory the refused run made is removed; a run that sets up leaves nothing set aside."""
    out = tmp_path / "out"
    base = ["run", CASES / "taylor_green.toml", "--out", out, "--quiet", "--set", "domain.dx=0.1", "--set",
            "time.t_end=0.02", "--set", "output.checkpoint_every=2"]
    assert run_psph(*base, ranks=ranks).returncode == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert any(name.startswith("checkpoint_") for name in before)
    res = run_psph(*base, "--overwrite", "--set", "initial.fill_lower=[0.31, 0.31]", "--set",
                   "initial.fill_upper=[0.32, 0.32]", ranks=ranks)
    assert res.returncode == 2 and "no lattice node" in res.stderr and "Traceback" not in res.stderr, res.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    kinematic = ["run", CASES / "kinematic_tgv.toml", "--quiet", "--set", "domain.dx=0.1", "--set",
                 "initial.sigma_over_dx=0", "--set", "iips.pre_newton=3", "--set", "diagnostics.test_wavelength=1.0"]
    res = run_psph(*kinematic, "--out", out, "--overwrite", ranks=ranks)
    assert res.returncode == 2 and "iips.beta" in res.stderr, res.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    res = run_psph(*kinematic, "--out", tmp_path / "new", ranks=ranks)
    assert res.returncode == 2 and not (tmp_path / "new").exists(), res.stderr
    assert run_psph(*base, "--overwrite", "--set", "time.t_end=0.01", ranks=ranks).returncode == 0
    assert not (out / ".psph_replaced").exists() and json.loads((out / "summary.json").read_text())["steps"] < 6


INJECTED_REFUSAL = """
import sys
from psph.drivers import fluid
from psph.errors import SceneError
build = fluid.FluidDriver._build
def refuse(self, scene, comm, restart):
    build(self, scene, comm, restart)
    raise SceneError("time.t_end", "refused late (injected)")
fluid.FluidDriver._build = refuse
from psph.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_a_continuation_refused_while_it_sets_up_leaves_its_directory_as_it_was(tmp_path):
    """A restarts audit: an in-place continuation refused as bad input before it had set up removed every
    result in its directory, the checkpoint it continued included (the refusal path cleared the directory as
    for a fresh run's own files), and the results past the checkpoint before that. No such refusal of a
    restart exists in psph today (a future one would take this path), so this one is injected after the
    driver's build. The directory is then byte for byte as it was, and the same continuation without the
    refusal runs and leaves nothing set aside."""
    import subprocess
    import sys

    from tests.helpers import mpi_environment

    out = tmp_path / "out"
    done = run_psph("run", CASES / "taylor_green.toml", "--out", out, "--quiet", "--set", "domain.dx=0.1", "--set",
                    "time.t_end=0.02", "--set", "output.checkpoint_every=4", "--set", "output.every=0.005")
    assert done.returncode == 0, done.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    checkpoint = out / "checkpoint_000004.h5"  # of 6 steps: two snapshots and the summary past it
    assert checkpoint.name in before and "snapshot_000004.h5" in before and "summary.json" in before
    (tmp_path / "inject.py").write_text(INJECTED_REFUSAL)
    res = subprocess.run([sys.executable, tmp_path / "inject.py", "run", "--restart", checkpoint, "--overwrite",
                          "--quiet"], capture_output=True, text=True, timeout=300, env=mpi_environment())
    assert res.returncode == 2 and res.stderr.strip() == "psph: error: time.t_end: refused late (injected)", res.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    res = run_psph("run", "--restart", checkpoint, "--overwrite", "--quiet")
    assert res.returncode == 0, res.stderr
    assert not (out / ".psph_replaced").exists() and json.loads((out / "summary.json").read_text())["steps"] > 2


ONE_D = ["--set", "domain.dimension=1", "--set", "domain.lower=[0.0]", "--set", "domain.upper=[1.0]", "--set",
         "domain.periodic=[true]"]


@pytest.mark.parametrize("options", [
    ["-iips_mat_type", "sell"],  # PETSc 3.18's SELL mangled a trial of 4 block rows per rank
    ["-iips_mat_type", "dense"],
    ONE_D + ["-iips_mat_type", "baij", "-iips_pc_type", "gamg"],  # BAIJ of block size 1 is AIJ (a traceback)
    ["-iips_pc_type", "hypre"]])
def test_the_trial_solve_refuses_no_solver_that_works(tmp_path, options):
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path, "--quiet", "--set", "domain.dx=0.1",
                   "--set", "shifting.method=iips", "--set", "iips.max_newton=2", *options)
    assert res.returncode == 0, res.stderr
    assert json.loads((tmp_path / "summary.json").read_text())["steps"] == 2


def test_the_trial_solve_leaves_the_iteration_cap_to_the_run(tmp_path):
    """A small -iips_ksp_max_it with iips.on_failure = "reject" is a choice (cap the solves, undo the calls
    they fail), not a solver that does not work: the trial lets it pass, and the run rejects its call. The
    run's end warns of the rejected calls on stderr, with --quiet too."""
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path, "--set", "domain.dx=0.1", "--set",
                   "shifting.method=iips", "--set", "iips.on_failure=reject", "-iips_ksp_max_it", "1")
    assert res.returncode == 0, res.stderr
    assert "IIPS call rejected: iips linear solve diverged: DIVERGED_MAX_IT after 1 iterations" in res.stdout
    warning = "psph: warning: 1 IIPS call(s) were rejected and their displacements undone"
    assert res.stderr.startswith(warning) and warning in (tmp_path / "psph.log").read_text(), res.stderr
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path, "--set", "domain.dx=0.1", "--set",
                   "shifting.method=iips", "--set", "iips.on_failure=reject", "-iips_ksp_max_it", "1", "--quiet",
                   "--overwrite")
    assert res.returncode == 0 and res.stdout == "" and res.stderr.startswith(warning), res.stdout + res.stderr
    assert json.loads((tmp_path / "summary.json").read_text())["steps"] == 0


def test_a_petsc_flag_before_the_scene_is_told_to_go_after_it(tmp_path):
    """A PETSc option takes the next word for its value: before the scene file it took the scene, and psph
    only said that run needs a scene file (a PETSc-options audit)."""
    res = run_psph("run", "-iips_ksp_monitor", CASES / "static_perturbed.toml", "--out", tmp_path / "out")
    assert res.returncode == 2 and not (tmp_path / "out").exists()
    assert res.stderr.strip().startswith("psph: error: run needs a scene file (or --restart CHECKPOINT): PETSc "
                                         "options go after it ('-iips_ksp_monitor "), res.stderr
    assert "static_perturbed.toml' took the scene as the option's value)" in res.stderr


@pytest.mark.parametrize("on_failure", ["stop", "reject"])
def test_petsc_raising_on_a_solve_that_did_not_converge_is_a_diverged_solve(tmp_path, on_failure):
    """-iips_ksp_error_if_not_converged makes PETSc raise where it would return a diverged reason: the run
    exited 1 with no step or particle named, and "reject" did not reject (a PETSc-options audit). It is the
    diverged solve psph handles by iips.on_failure."""
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path, "--quiet", "--set", "domain.dx=0.05",
                   "--set", "shifting.method=iips", "--set", f"iips.on_failure={on_failure}", "-iips_ksp_max_it", "5",
                   "-iips_ksp_error_if_not_converged")
    diverged = "iips linear solve diverged: DIVERGED_MAX_IT after 5 iterations"
    if on_failure == "stop":
        assert res.returncode == 3 and res.stderr.startswith(f"psph: error: {diverged} [iteration 1, particle gid")
    else:
        assert res.returncode == 0 and f"IIPS call rejected: {diverged}" in (tmp_path / "psph.log").read_text()


def test_a_solver_viewer_to_a_file_keeps_every_solve(tmp_path):
    """A PETSc-options audit: -iips_ksp_converged_reason ascii:F kept 1 line of 291, -iips_ksp_view ascii:F none:
    each neighbour-list rebuild's new KSP opened F for writing again. F is emptied once and appended to: it
    holds what the terminal gets, on 2 ranks."""
    sets = ["--quiet", "--set", "domain.dx=0.05", "--set", "time.t_end=0.02", "--set", "output.every=0"]
    on_screen = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path / "a", *sets,
                         "-iips_ksp_converged_reason", ranks=2)
    (tmp_path / "reasons.txt").write_text("an earlier run's\n")
    to_file = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path / "b", *sets,
                       "-iips_ksp_converged_reason", f"ascii:{tmp_path}/reasons.txt", ranks=2)
    assert on_screen.returncode == 0 and to_file.returncode == 0, to_file.stderr
    lines = [ln for ln in on_screen.stdout.splitlines() if ln.startswith("Linear iips_ solve")]
    assert len(lines) > 20 and (tmp_path / "reasons.txt").read_text().splitlines() == lines
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["neighbour_rebuilds"] > 1
    # a viewer file named in an options file, which the command line's check does not see: one line, exit 2,
    # nothing written (a review: rank 0's failure to empty it was an input/output error, exit 1, an MPI_ABORT
    # on 2 ranks)
    (tmp_path / "bad.opts").write_text(f"-iips_ksp_converged_reason ascii:{tmp_path}/missing/reasons.txt\n")
    bad = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path / "c", *sets, "-options_file",
                   tmp_path / "bad.opts", ranks=2)
    assert bad.returncode == 2 and not (tmp_path / "c").exists(), bad.stderr
    assert f"psph: error: -iips_ksp_converged_reason ascii:{tmp_path}/missing/reasons.txt: cannot write" in bad.stderr


def test_solves_that_meet_their_tolerance_only_in_the_preconditioned_residual_are_warned_about(tmp_path):
    """A PETSc-options audit: with ILU (left-preconditioned) the solves stopped at rtol in the preconditioned
    residual while the true one stayed near |b|; the static run ended at L2(grad C) 3.4e-3 against Jacobi's
    1.4e-4, exit 0, no word. The true residual of each solve with a non-diagonal preconditioner is checked,
    and the loose ones are counted in a warning; Jacobi's solves are not checked."""
    base = ["run", CASES / "static_perturbed.toml", "--quiet", "--set", "domain.dx=0.05", "--set",
            "shifting.method=iips", "--set", "iips.max_newton=5"]
    res = run_psph(*base, "--out", tmp_path / "ilu", "-iips_pc_type", "ilu")
    assert res.returncode == 0, res.stderr
    assert re.match(r"psph: warning: [1-5] of 5 -iips_ solves met their tolerance in the preconditioned residual "
                    r"while the true residual \|b - A x\| stayed up to .* \(PC ilu", res.stderr), res.stderr
    assert "preconditioned residual" in (tmp_path / "ilu" / "psph.log").read_text()
    res = run_psph(*base, "--out", tmp_path / "jacobi")
    assert res.returncode == 0 and res.stderr == "", res.stderr


def test_the_trial_solve_prints_nothing(tmp_path):
    """The trial solve runs without the options that make a solve print: -iips_ksp_view and
    -iips_ksp_converged_reason print once per Newton iteration of the run, on a Python (matrix-free) matrix."""
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path, "--set", "domain.dx=0.1", "--set",
                   "shifting.method=iips", "-iips_ksp_view", "-iips_ksp_converged_reason", "-iips_ksp_monitor")
    assert res.returncode == 0, res.stderr
    newton = json.loads((tmp_path / "summary.json").read_text())["steps"]
    assert newton > 0
    assert res.stdout.count("Linear iips_ solve converged") == newton
    assert res.stdout.count("KSP Object: (iips_)") == newton
    assert res.stdout.count("type: python") == newton and "seqaij" not in res.stdout
    assert res.stdout.count(" 0 KSP Residual norm") == newton
    # an inner solver's view and the convergence rate: the trial's 4 block rows (8 rows in 2-D) never show
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path / "b", "--set", "domain.dx=0.1",
                   "--set", "shifting.method=iips", "--set", "iips.max_newton=2", "-iips_pc_type", "bjacobi",
                   "-iips_sub_ksp_view", "-iips_ksp_converged_rate")
    assert res.returncode == 0, res.stderr
    assert res.stdout.count("Linear iips_ solve converged") == 2 and "rows=8," not in res.stdout
    assert "rows=200," in res.stdout  # the run's own sub-solver


def test_a_log_inside_a_new_output_directory(tmp_path):
    out = tmp_path / "new"
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", out, "--log", out / "my.log", "--quiet",
                   "--set", "domain.dx=0.1")
    assert res.returncode == 0, res.stderr
    assert "running scene" in (out / "my.log").read_text() and (out / "summary.json").exists()


def test_a_flow_with_iips_and_no_threshold_is_warned_about(tmp_path):
    """Without iips.threshold or iips.beta every call of a flow runs all iips.max_newton iterations, on past
    convergence (a rank audit: the elliptical drop then differed by 0.15 dx between 1 and 2 ranks)."""
    tgv = CASES / "taylor_green.toml"
    sets = ["--set", "domain.dx=0.1", "--set", "time.t_end=0.02", "--set", "iips.max_newton=2",
            "--set", "output.every=0"]
    bare = run_psph("run", tgv, "--out", tmp_path / "bare", "--quiet", *sets, "--set", "iips.threshold=0")
    assert bare.returncode == 0, bare.stderr
    assert "warning: iips.threshold = 0 (and no iips.beta): every IIPS call of this run iterates until " \
           "iips.max_newton = 2" in bare.stderr
    assert "warning: iips.threshold" in (tmp_path / "bare" / "psph.log").read_text()
    kept = run_psph("run", tgv, "--out", tmp_path / "kept", "--quiet", *sets)
    assert kept.returncode == 0 and "warning" not in kept.stderr, kept.stderr


@pytest.mark.parametrize("c0, dissipation, warned", [(100.0, "full", True), (10.0, "full", False),
                                                    (100.0, "low", False)])
def test_the_riemann_scheme_at_low_mach_is_warned_about(tmp_path, c0, dissipation, warned):
    """The acoustic solver's dissipation grows with c0/U (a Riemann audit: -89% kinetic energy by t = 0.01 at
    c0/U = 1000, exit 0); riemann_dissipation = "low" does not."""
    res = run_psph("run", CASES / "taylor_green.toml", "--out", tmp_path, "--quiet", "--set", "domain.dx=0.1",
                   "--set", "time.t_end=0.002", "--set", "physics.scheme=riemann_ale", "--set",
                   f"physics.sound_speed={c0}", "--set", f"physics.riemann_dissipation={dissipation}",
                   "--set", "shifting.method=none", "--set", "iips.update=none", "--set", "output.every=0")
    assert res.returncode == 0, res.stderr
    assert ("warning: physics.sound_speed / reference_velocity = 100: the acoustic Riemann solver's dissipation"
            in res.stderr) is warned, res.stderr


@pytest.mark.parametrize("scheme, cfl, warned", [("riemann_ale", 1.0, True), ("riemann_ale", 0.8, False),
                                                 ("delta_ale", 1.0, False)])
def test_a_riemann_time_step_beyond_its_stable_cfl_is_warned_about(tmp_path, scheme, cfl, warned):
    """riemann_ale blows up from time.cfl = 1.0 (2-D) and 1.2 (1-D), and the failure then names the density or
    the skin, not the step (a Riemann audit); delta_ale with delta+ ran Taylor-Green at 1.5."""
    res = run_psph("run", CASES / "taylor_green.toml", "--out", tmp_path, "--quiet", "--set", "domain.dx=0.1",
                   "--set", "time.t_end=0.02", "--set", f"physics.scheme={scheme}", "--set", f"time.cfl={cfl}",
                   "--set", "neighbours.skin=0.5", "--set", "shifting.method=none", "--set", "iips.update=none",
                   "--set", "output.every=0")
    assert res.returncode == 0, res.stderr
    assert (f'warning: time.cfl = {cfl:g} with physics.scheme = "riemann_ale": the scheme runs stably up to about '
            "0.8" in res.stderr) is warned, res.stderr


@pytest.mark.parametrize("periodic, said", [("[true, false]", "y-, y+"), ("[true, true]", None)])
def test_a_fluid_reaching_a_bounded_face_with_nothing_there_is_warned_about(tmp_path, periodic, said):
    """A 3-D audit: a box of fluid at rest with bare faces stopped at step 6 on its density (delta+ pushed the
    particles along the faces out), naming neither the faces nor the cause; a periodic box of side 0.6 was
    refused over diagnostics.test_wavelength, which no flow reads."""
    res = run_psph("run", CASES / "taylor_green.toml", "--out", tmp_path, "--quiet", "--set", "domain.dx=0.1",
                   "--set", "domain.upper=[0.6, 0.6]", "--set", "time.t_end=0.005", "--set", "output.every=0",
                   "--set", f"domain.periodic={periodic}", "--set", "initial.velocity=zero")
    assert res.returncode == (3 if said else 0), res.stderr  # (its perturbed start's bare rows leave at step 1)
    warning = "warning: the fluid reaches the bounded face(s) "
    assert (warning in res.stderr) is (said is not None), res.stderr
    if said:
        assert f"{warning}{said} with no wall, outflow or inflow there (domain.periodic = [True, False])" in res.stderr
    info = run_psph("info", CASES / "taylor_green.toml", "--set", "diagnostics.test_wavelength=0.3")
    assert info.returncode == 0 and "diagnostics.test_wavelength" in info.stdout, info.stderr
    kinematic = run_psph("info", CASES / "kinematic_tgv.toml", "--set", "diagnostics.test_wavelength=0.3")
    assert kinematic.returncode == 2 and "diagnostics.test_wavelength: must divide" in kinematic.stderr


@pytest.mark.parametrize("update, warned", [("mls1", True), ("mls1_increment", False), ("mls2", False)])
def test_the_plain_first_order_remap_in_a_flow_is_warned_about(tmp_path, update, warned):
    """iips.update = mls1 smooths every field at every call (Taylor-Green at dx = 0.05: kinetic energy -99.8%
    by t = 1, a field-update audit's one call -5.2%)."""
    res = run_psph("run", CASES / "taylor_green.toml", "--out", tmp_path, "--quiet", "--set", "domain.dx=0.1",
                   "--set", "time.t_end=0.01", "--set", f"iips.update={update}", "--set", "output.every=0")
    assert res.returncode == 0, res.stderr
    assert ("warning: iips.update = mls1 replaces every field by its first-order fit" in res.stderr) is warned, \
        res.stderr


@pytest.mark.parametrize("update", ["mls2", "mls1", "mls2_increment", "nfts"])
def test_no_field_update_with_a_free_surface_is_warned_about(tmp_path, update):
    """The plain remaps were warned about at a free surface (the dam break at H/dx = 10 to t = 3: kinetic
    energy 0.079 against 0.450), a loss that was the MLS fits' solid particles (CHANGELOG): since the fit is the
    fluid's, mls2 ends with 0.469 and its mass to 8e-6, and no update is warned about for the free surface
    (mls1 is, for its smoothing everywhere)."""
    res = run_psph("run", CASES / "dam_break.toml", "--out", tmp_path / "out", "--quiet", "--set", "domain.dx=0.1",
                   "--set", "time.t_end=0.01", "--set", "shifting.method=iips", "--set", f"iips.update={update}")
    assert res.returncode == 0, res.stderr
    warnings = [line for line in res.stderr.splitlines() if "warning" in line]
    assert warnings == (["psph: warning: iips.update = mls1 replaces every field by its first-order fit at every "
                         "IIPS call, which smooths the flow (Taylor-Green at dx = 0.05 from a relaxed start: kinetic "
                         "energy -99.8% by t = 1, against -0.07% with no update; one call took 5.2%); "
                         "mls1_increment adds only the fit's change, and mls2 smooths less"]
                        if update == "mls1" else []), res.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary.get("mls_fallbacks") == (0 if update.startswith("mls") else None)  # (a full support everywhere)


def test_nfts_from_a_perturbed_start_without_pre_procedure_is_warned_about(tmp_path):
    """A field-update audit: NFTS's mass and volume lines differ by 2 rho V s . grad C (thesis eq. 9.7), so the
    first calls on a perturbed start change a uniform density. The thesis' Taylor-Green (sigma = 0.25 dx)
    without its pre-procedure leaves the weakly compressible range at step 1; with it, the run goes on, and
    its summary counts the NFTS sub-steps of eq. 9.6 (N = ceil(max|dx| / (time.cfl dx)), time.cfl 0.1 here)."""
    tgv = CASES / "taylor_green_thesis.toml"
    sets = ["--set", "domain.dx=0.05", "--set", "time.t_end=0.01", "--set", "output.every=0", "--quiet"]
    bare = run_psph("run", tgv, "--out", tmp_path / "bare", *sets, "--set", "iips.pre_newton=0")
    assert bare.returncode == 3 and "density left the weakly compressible range" in bare.stderr, bare.stderr
    assert "warning: initial.sigma_over_dx = 0.25 with iips.update = nfts and no iips.pre_newton" in bare.stderr
    kept = run_psph("run", tgv, "--out", tmp_path / "kept", *sets, "--set", "iips.procedure=A",
                    "--set", "time.cfl=0.1")
    assert kept.returncode == 0 and "warning" not in kept.stderr, kept.stderr
    summary = json.loads((tmp_path / "kept" / "summary.json").read_text())
    assert summary["iips_calls"] > 0 and summary["nfts_substeps"] >= summary["iips_calls"]
    from psph.scene.load import load_scene
    from psph.shifting.field_update import make_field_update

    assert make_field_update(load_scene(tgv, ["time.cfl=0.05"])).cfl == 0.05  # (it was 0.2 whatever time.cfl)


def test_the_iips_solver_the_options_give_is_reported(tmp_path):
    """A drivers audit: psph info said "default bcgs + jacobi" whatever the options, and a run recorded
    neither the solver nor whether iips.operator = "auto" chose the matrix-free or the assembled operator."""
    options = ["-iips_ksp_type", "gmres", "-iips_pc_type", "gamg", "-iips_ksp_rtol", "1e-3"]
    sets = ["--set", "shifting.method=iips", "--set", "domain.dx=0.1", "--set", "iips.max_newton=2"]
    expected = "IIPS linear solver: KSP gmres + PC gamg, rtol 0.001, max_it 10000, assembled aij matrix"
    info = run_psph("info", SCENE, *sets, *options)
    assert info.returncode == 0 and expected in info.stdout, info.stdout + info.stderr
    res = run_psph("run", SCENE, "--out", tmp_path, "--quiet", *sets, *options)
    assert res.returncode == 0, res.stderr
    assert "psph: " + expected in (tmp_path / "psph.log").read_text()
    solver = json.loads((tmp_path / "summary.json").read_text())["iips_solver"]
    assert solver == {"ksp_type": "gmres", "pc_type": "gamg", "rtol": 1e-3, "atol": 1e-50, "max_it": 10000,
                      "operator": "assembled", "mat_type": "aij"}
    default = run_psph("info", SCENE, *sets)
    assert "KSP bcgs + PC jacobi, rtol 0.01, max_it 10000, matrix-free operator" in default.stdout


def test_a_set_key_the_run_does_not_read_is_warned_about(tmp_path):
    """A drivers audit: --set time.retries=3 on a kinematic run (which retries nothing), or iips.max_newton with
    the explicit iteration, ran with exit 0 and no word. A scene file's keys for other methods are only listed
    by psph info (cases/dam_break.toml holds IIPS's for --set shifting.method=iips)."""
    kinematic = ["run", CASES / "kinematic_tgv.toml", "--quiet", "--set", "domain.dx=0.1", "--set", "time.t_end=0.01",
                 "--set", "iips.pre_newton=5"]
    res = run_psph(*kinematic, "--out", tmp_path / "a", "--set", "time.retries=3", "--set",
                   "shifting.method=explicit_iterative", "--set", "iips.max_newton=3")
    assert res.returncode == 0, res.stderr
    assert "psph: warning: --set keys this run does not read: iips.max_newton, time.retries (physics.scheme = " \
           "'kinematic', shifting.method = 'explicit_iterative')" in res.stderr
    quiet = run_psph(*kinematic, "--out", tmp_path / "b")
    assert quiet.returncode == 0 and "does not read" not in quiet.stderr, quiet.stderr
    # (a kinematic audit: its field's L is the domain's, and physics.reference_length went unmentioned)
    length = run_psph("info", kinematic[1], "--set", "physics.reference_length=2", "--set", "physics.eos=tait")
    assert "does not read (another method's?): physics.reference_length, physics.eos (" in length.stdout, length.stdout
    fluid = run_psph("info", CASES / "taylor_green.toml", "--set", "physics.reference_length=2")
    assert "does not read" not in fluid.stdout, fluid.stdout
    info = run_psph("info", CASES / "dam_break.toml")
    assert "# keys set that this run does not read (another method's?): iips.procedure, iips.threshold" in info.stdout
    unscaled = run_psph("info", kinematic[1], "--set", "iips.beta=0", "--set", "iips.threshold=0.001", "--set",
                        "iips.beta_from=lowest")  # (no beta to scale)
    assert "does not read (another method's?): iips.beta_from (" in unscaled.stdout, unscaled.stdout
    scaled = run_psph("info", kinematic[1], "--set", "iips.beta_from=lowest")
    assert "does not read" not in scaled.stdout, scaled.stdout


def test_a_stopped_runs_fields_have_grad_c_from_its_checkpoints_scene(tmp_path):
    """An I/O audit: a run stopped by a signal has no summary.json, and its fields.png left out |grad C| h
    without a word; the newest checkpoint holds the scene too."""
    from psph import plot
    from psph.studies import last_snapshot

    res = run_psph("run", CASES / "taylor_green.toml", "--out", tmp_path, "--quiet", "--set", "domain.dx=0.1",
                   "--set", "time.t_end=0.05", "--set", "output.every=0.02", "--checkpoint-every", "10")
    assert res.returncode == 0, res.stderr
    data, _ = last_snapshot(tmp_path)
    finished = plot._grad_c_magnitude(tmp_path, data)
    (tmp_path / "summary.json").unlink()  # as a stopped run leaves it
    stopped = plot._grad_c_magnitude(tmp_path, data)
    assert finished is not None and stopped is not None and np.array_equal(stopped, finished)
    assert np.abs(stopped).max() > 0.0


@pytest.mark.parametrize("h_over_dx,diffusion,warned", [(1.3, 0.4, True), (2.0, 0.4, False), (2.0, 0.5, True)])
def test_a_fickian_coefficient_above_the_kernels_stability_limit_is_warned_about(tmp_path, h_over_dx, diffusion,
                                                                                 warned):
    """The default 0.4 h^2 is stable with C6 at h/dx = 2 (limit 0.47) and not at 1.3 (0.27), where the explicit
    iteration degrades the distribution it should relax (an audit: L2(grad C) 0.33 -> 0.62 in 300 iterations;
    here, at dx = 0.1, the run stops after 2 iterations with the distribution worse than it started)."""
    res = run_psph("run", SCENE, "--out", tmp_path / "out", "--quiet", "--set", "domain.dx=0.1", "--set",
                   "shifting.method=explicit_iterative", "--set", "shifting.max_iterations=2", "--set",
                   f"domain.h_over_dx={h_over_dx}", "--set", f"shifting.diffusion={diffusion}")
    assert res.returncode == (3 if h_over_dx == 1.3 else 0), res.stderr
    assert ("warning: shifting.diffusion" in res.stderr) is warned, res.stderr
    if warned:
        assert f"shifting.diffusion = {diffusion:g} exceeds {0.275 if h_over_dx == 1.3 else 0.472}" in res.stderr


@pytest.mark.parametrize("diffusion,warned", [(None, False), (0.4, True)])
def test_linds_coefficient_is_checked_against_its_corrected_gradients_limit(tmp_path, diffusion, warned):
    """Lind's law steps on grad C^, whose lattice limit (0.329 h^2 in 2-D with C6 at h/dx = 2) is below the
    plain gradient's 0.472: 0.4 h^2, which it took from the explicit iteration, was not warned about (a
    dimensions audit: a 1-D stream sped up to 1.12 U). Its own default, 0.2 h^2, is within the limit."""
    sets = ["--set", "shifting.method=lind", "--set", "iips.update=none", "--set", "time.t_end=0.002"]
    if diffusion is not None:
        sets += ["--set", f"shifting.lind_diffusion={diffusion}"]
    res = run_psph("run", CASES / "taylor_green.toml", "--out", tmp_path / "out", "--quiet", "--set",
                   "domain.dx=0.1", *sets)
    assert res.returncode == 0, res.stderr
    assert ("psph: warning: shifting.lind_diffusion = 0.4 exceeds 0.329, the limit above which dx = -D grad C^ "
            "(thesis eq. 6.16) amplifies" in res.stderr) is warned, res.stderr
    assert "warning" not in res.stderr or warned, res.stderr


def test_a_viewer_path_with_petscs_variables_is_left_to_petsc(tmp_path):
    """PETSc expands ${WORKINGDIRECTORY} and the like in a viewer's file name: the check refused such a path
    as a missing directory (a review); it is PETSc's to expand, and the profile is written."""
    res = run_psph("run", SCENE, "--out", tmp_path / "out", "--quiet", "--set", "domain.dx=0.1", "-log_view",
                   ":${WORKINGDIRECTORY}/profile.txt", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "Performance Summary" in (tmp_path / "profile.txt").read_text()


def test_petsc_options_petsc_cannot_start_with_are_one_line_of_psph(tmp_path):
    """-options_file naming no file: PETSc reports it and petsc4py raised, which psph took for its own bug
    (exit 1 and a traceback; a fuzzing audit). It is bad input: exit 2, one psph line, nothing written."""
    missing = tmp_path / "missing.txt"  # refused by psph before PETSc starts (test_failures: on 2 ranks it hung)
    res = run_psph("run", SCENE, "--out", tmp_path / "out", "--quiet", "--set", "domain.dx=0.1", "-options_file",
                   str(missing))
    assert res.returncode == 2 and res.stderr.strip() == f"psph: error: -options_file {missing}: no file " \
                                                         f"'{missing}' to read", res.stderr
    # through PETSc's variables, which psph leaves to PETSc
    res = run_psph("run", SCENE, "--out", tmp_path / "out", "--quiet", "--set", "domain.dx=0.1", "-options_file",
                   "${WORKINGDIRECTORY}/missing.txt", cwd=tmp_path)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert res.stderr.strip().splitlines()[-1] == ("psph: error: PETSc did not start with the options -options_file "
                                                   "${WORKINGDIRECTORY}/missing.txt: error code 83 (PETSc's report "
                                                   "above)")
    # a directory, and a missing file named in PETSC_OPTIONS (a review: "no file ... to read", "the options (none)")
    res = run_psph("run", SCENE, "--out", tmp_path / "out", "--quiet", "-options_file", str(tmp_path))
    assert res.returncode == 2 and res.stderr.strip() == f"psph: error: -options_file {tmp_path}: '{tmp_path}' " \
                                                         "is a directory", res.stderr
    env = {**mpi_environment(), "PETSC_OPTIONS": f"-options_file {missing}"}
    res = subprocess.run([sys.executable, "-m", "psph", "info", str(SCENE)], capture_output=True, text=True, cwd=ROOT,
                         env=env, timeout=120)
    assert res.returncode == 2 and res.stderr.strip().splitlines()[-1].startswith(
        f"psph: error: PETSc did not start with the options of PETSC_OPTIONS='-options_file {missing}'"), res.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("option,value", [("-log_view", ":{bad}"), ("-iips_ksp_view", "ascii:{bad}:ascii_info"),
                                          ("-iips_ksp_converged_reason", "ascii:{bad}")])
def test_viewer_files_that_cannot_be_written_are_refused_before_the_run(tmp_path, option, value):
    """PETSc opens -log_view's file in PetscFinalize, after the run: `-log_view :/no/dir/x` printed PETSc's
    error and exited 0, the profile lost (a fuzzing audit). A viewer whose file cannot be written is bad
    input, refused before anything is written."""
    bad = tmp_path / "no" / "log.txt"
    value = value.format(bad=bad)
    res = run_psph("run", SCENE, "--out", tmp_path / "out", "--quiet", "--set", "domain.dx=0.1", option, value)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert res.stderr.strip().splitlines()[-1] == (f"psph: error: {option} {value}: cannot write '{bad}' "
                                                   f"(no directory '{bad.parent}')")
    assert not (tmp_path / "out").exists()


def test_petsc_s_stream_viewers_are_no_files():
    """ascii:stdout and ascii:stderr name PETSc's streams, not files in the working directory (a review: in a
    directory psph cannot write they would have been refused)."""
    from psph.solvers.petsc import viewer_file

    assert viewer_file("ascii:stdout") is None and viewer_file("ascii:stderr:ascii_info") is None
    assert viewer_file("ascii:out.txt") == ["ascii", "out.txt", "", ""]


def test_plot_colours_the_fluid_only_and_takes_damaged_or_empty_columns(tmp_path, monkeypatch):
    """A plot audit: fields.png coloured the walls' stand-in values (the cavity's outer wall layers' |grad C| h
    of 0.9 set the scale of a fluid at 0.04; the moving lid showed |u| = 0); a probes.csv row cut short, or a
    history without a time column, was an internal error; an all-NaN history column drew an empty panel with
    numpy's warning."""
    import warnings

    import matplotlib.pyplot as plt

    import psph.plot as plot_module
    from psph.errors import UsageError
    from psph.particles import Kind
    from psph.studies import last_snapshot

    out = tmp_path / "cavity"
    res = run_psph("run", CASES / "lid_driven_cavity.toml", "--out", out, "--quiet", "--set", "domain.dx=0.1",
                   "--set", "time.t_end=0.05", "--set", "output.probes=[[0.5, 0.5], [0.5, 0.9]]")
    assert res.returncode == 0, res.stderr
    figures = {}

    def keep(plt_, fig, path, title=None):
        figures[path.name] = fig
        return path

    monkeypatch.setattr(plot_module, "_save", keep)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plot_module.plot(out)
    data, _ = last_snapshot(out)
    fluid = data["kind"] == Kind.FLUID
    speed = np.linalg.norm(data["velocity"], axis=1)
    coloured = [c for c in figures["fields.png"].axes[0].collections if c.get_array() is not None]
    assert len(coloured) == 1 and coloured[0].get_clim() == pytest.approx((speed[fluid].min(), speed[fluid].max()))
    assert len(coloured[0].get_array()) == fluid.sum() < len(fluid)
    plt.close("all")
    probes = out / "probes.csv"
    probes.write_text(probes.read_text() + "0.06,1.0\n")  # a row cut short (a run killed while writing it)
    history = out / "history.csv"
    lines = history.read_text().splitlines()
    header = lines[0].split(",")
    nan_column = header.index("L2_grad_c")
    history.write_text("\n".join([lines[0]] + [",".join("nan" if k == nan_column else v for k, v in
                                                        enumerate(line.split(","))) for line in lines[1:]]) + "\n")
    figures.clear()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plot_module.plot(out)
    titles = [ax.get_title() for ax in figures["history.png"].axes]
    assert "L2_grad_c" not in titles and "kinetic_energy" in titles
    plt.close("all")
    history.write_text("step,kinetic_energy\n1,2.0\n")
    with pytest.raises(UsageError, match=r"history.csv' is not a psph history: no time column"):
        plot_module.plot(out)


@pytest.mark.parametrize("case, sets, warned", [
    ("hydrostatic_tank", ["physics.gravity=[0.0, -9.81]"], "is 3.19 times sqrt(|g| H) = 3.13, the speed gravity "
                                                            "gives a fluid 1 deep"),
    ("hydrostatic_tank", [], None),  # the tank's own c0 = 10 sqrt(g H)
    ("trapezoidal_tank", ["physics.gravity=[0.0, -4.0]"], "is 5 times sqrt(|g| H) = 2,"),
    ("dam_break", ["physics.sound_speed=5"], None),  # its Mach number says it: U = sqrt(2 g H) > sqrt(g H)
    ("taylor_green", ["physics.gravity=[0.0, -9.81]"], None),  # periodic along gravity: it falls, freely
])
def test_a_sound_speed_slow_against_gravity_waves_is_warned_about(case, sets, warned):
    """A new user's audit: g = 9.81 with c0 = 10 over a 1-deep tank started at 98% of the density limit (the
    weight compresses its foot by g H / c0^2) without a word, and stopped at step 32 naming the density."""
    from psph.cli import scene_warnings
    from psph.scene.load import load_scene

    found = [w for w in scene_warnings(load_scene(CASES / f"{case}.toml", sets)) if "sqrt(|g| H)" in w]
    assert (found == []) if warned is None else (len(found) == 1 and warned in found[0]), found


@pytest.mark.parametrize("case, sets, warned", [
    ("lid_driven_cavity", ["physics.scheme=riemann_ale"], "with iips.update = 'nfts'"),  # the scene's IIPS + NFTS
    ("lid_driven_cavity", ["physics.scheme=riemann_ale", "shifting.method=delta_plus", "iips.update=none"],
     "with shifting.method = 'delta_plus'"),
    ("lid_driven_cavity", ["physics.scheme=riemann_ale", "shifting.method=neuhauser", "iips.update=none"],
     "with shifting.method = 'neuhauser'"),
    ("lid_driven_cavity", ["physics.scheme=riemann_ale", "shifting.method=neuhauser", "iips.update=none",
                           "shifting.fictitious_pressure=true"], None),  # the thesis' P^F ties shift and volume
    ("lid_driven_cavity", ["physics.scheme=riemann_ale", "iips.update=none"], None),
    ("lid_driven_cavity", ["physics.scheme=riemann_ale", "iips.update=mls2"], None),
    ("lid_driven_cavity", ["physics.scheme=riemann_ale", "shifting.method=none", "iips.update=none"], None),
    ("lid_driven_cavity", [], None),  # delta-ALE's density pushes a squeezed particle back
    ("taylor_green", ["physics.scheme=riemann_ale", "shifting.method=delta_plus", "iips.update=none"], None),
    # a moving body: every shifting measured stopped SPHERIC 6's square, even the ones fixed walls take
    ("moving_square", ["physics.scheme=riemann_ale"], "a moving body (bodies[1] 'square')"),
    ("moving_square", ["physics.scheme=riemann_ale", "shifting.method=neuhauser", "shifting.fictitious_pressure=true",
                       "iips.update=none"],
     "a moving body (bodies[1] 'square') in physics.scheme = \"riemann_ale\" with shifting.method = 'neuhauser'"),
    ("moving_square", ["physics.scheme=riemann_ale", "physics.riemann_dissipation=low", "shifting.method=iips",
                       "iips.update=none"],
     "a moving body (bodies[1] 'square') in physics.scheme = \"riemann_ale\" with shifting.method = 'iips'"),
    ("moving_square", ["physics.scheme=riemann_ale", "bodies.1.motion.law=fixed", "bodies.1.motion.velocity=[]",
                       "bodies.1.motion.rotation_law=constant", "bodies.1.motion.angular_velocity=1.0"],
     "a moving body (bodies[1] 'square')"),  # turning only
    ("moving_square", ["physics.scheme=riemann_ale", "shifting.method=none", "iips.update=none"], None),
    ("moving_square", [], None),
])
def test_shifting_that_shrinks_the_riemann_schemes_particles_at_walls_is_warned_about(case, sets, warned):
    """Walls in the Riemann scheme with a shift the volumes cannot hold against (run_scripts/riemann_walls.py:
    the cavity stopped with a volume drifted by 50% at t = 0.67 with delta_plus), or around a moving body with
    any shifting: warned at set-up (once), naming the settings that ran; without walls (Taylor-Green) or in
    delta-ALE-SPH, not."""
    from psph.cli import scene_warnings
    from psph.scene.load import load_scene

    found = [w for w in scene_warnings(load_scene(CASES / f"{case}.toml", sets)) if "riemann_ale\" with" in w]
    assert (found == []) if warned is None else (len(found) == 1 and warned in found[0]), found
