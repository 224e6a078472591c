"""The study harness of run_scripts/ (psph.studies.run_scene): a resumed study reads back the runs it
already made, complete or stopped by a diagnosis, instead of running them again."""

import argparse
import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from psph import studies
from psph.scene.load import load_scene

SETS = ["domain.dx=0.1", "time.t_end=0.02", "shifting.method=none", "iips.update=none", "output.every=0"]


@pytest.fixture(autouse=True)
def no_study_overrides(monkeypatch):
    """What a study's command line adds to every run (studies.parse_args) stays within its test."""
    monkeypatch.setattr(studies, "_EVERY_RUN", {"sets": [], "petsc": [], "allow_large": False})
    monkeypatch.setattr(studies, "_STUDY", {"out": None, "not_run": []})


def test_a_studys_set_and_petsc_options_reach_every_run(tmp_path):
    """Every study takes --set KEY=VALUE and PETSc options, as psph run does, and gives them to every run after
    its own overrides; a --set of a key the study sets itself to another value is refused (its tables label the
    runs with the study's values), but for how often a run writes (studies.WRITE_KEYS) and the keys the study
    reads back from its runs' scenes (settable)."""

    parser = argparse.ArgumentParser()
    parser.add_argument("--ranks", type=int, default=1)
    args = studies.parse_args(parser, ["--set", "domain.dx=0.2", "-iips_ksp_type", "gmres", "--ranks", "1",
                                       "--set", "iips.max_newton=2", "-iips_ksp_monitor", "--set",
                                       "output.every=0.5"])
    assert args.set == ["domain.dx=0.2", "iips.max_newton=2", "output.every=0.5"] and args.ranks == 1
    assert args.petsc == ["-iips_ksp_type", "gmres", "-iips_ksp_monitor"]
    with pytest.raises(studies.UsageError, match=r"^--set domain.dx=0.2: this study sets domain.dx on its runs "
                                                 r"itself \(domain.dx=0.1 in "):
        studies.run_scene(studies.CASES / "static_perturbed.toml", tmp_path / "refused",
                          sets=["domain.dx=0.1", "shifting.method=iips"])
    assert not (tmp_path / "refused").exists()  # nothing ran
    run = studies.run_scene(studies.CASES / "static_perturbed.toml", tmp_path / "run",
                            sets=["domain.dx=0.20", "shifting.method=iips", "output.every=0"])
    assert run.summary["n_particles"] == 25 and run.summary["steps"] == 2  # (0.20 is 0.2: no clash)
    assert [r["iteration"] for r in run.history] == [0, 1, 2]
    # the history rows a study reads are its own (a review: a dam break's average of probe rows moved 3x)
    with pytest.raises(studies.UsageError, match=r"^--set output.history_every=1: this study sets"):
        studies._EVERY_RUN["sets"] = ["output.history_every=1"]
        studies.study_command("s.toml", tmp_path, sets=["output.history_every=5"])
    studies.study_command("s.toml", tmp_path, sets=["domain.dx=0.1"], settable=("domain.dx",))  # no error
    command = (tmp_path / "run" / "study_command.json").read_text()
    assert '"-iips_ksp_type", "gmres", "-iips_ksp_monitor"' in command
    assert "nothing read" not in (tmp_path / "run" / "psph.log").read_text()  # the run read them


def test_a_resumed_study_reads_back_complete_and_stopped_runs(tmp_path, monkeypatch):
    scene = studies.CASES / "taylor_green.toml"
    done = studies.run_scene(scene, tmp_path / "done", sets=SETS, reuse=True)
    with pytest.raises(RuntimeError, match="density left the weakly compressible range") as first:
        studies.run_scene(scene, tmp_path / "stopped", sets=SETS + ["physics.max_density_variation=1e-6"],
                          reuse=True)

    def no_run(*args, **kwargs):
        raise AssertionError("the run was made again")

    monkeypatch.setattr(subprocess, "run", no_run)
    again = studies.run_scene(scene, tmp_path / "done", sets=SETS, reuse=True)
    assert again.summary == done.summary
    monkeypatch.chdir(tmp_path)
    elsewhere = studies.run_scene(scene, Path("done"), sets=SETS, reuse=True)  # relative spelling
    assert elsewhere.summary == done.summary
    with pytest.raises(RuntimeError) as second:
        studies.run_scene(scene, tmp_path / "stopped", sets=SETS + ["physics.max_density_variation=1e-6"],
                          reuse=True)
    assert str(second.value) == str(first.value)
    line = studies.stop_message(first.value)
    assert line.startswith("psph: error: the initial state: density left the weakly compressible range")
    assert "physics.sound_speed" not in line  # the tight limit caught it, not the equation of state
    # a table of the finished runs only: the finished one is read, another command is not run
    assert studies.run_scene(scene, tmp_path / "done", sets=SETS, only_finished=True).summary == done.summary
    with pytest.raises(studies.NotRun):
        studies.run_scene(scene, tmp_path / "done", sets=SETS + ["time.cfl=0.1"], only_finished=True)
    with pytest.raises(AssertionError, match="made again"):  # another command is a new run
        studies.run_scene(scene, tmp_path / "done", sets=SETS + ["time.cfl=0.1"], reuse=True)


def test_a_refused_run_is_a_failure_of_the_study_not_a_stop(tmp_path):
    """A bad key (exit 2) raises RunFailed with psph's one line, which no sweep takes for a diagnosed stop
    (RunStopped); the run's whole stderr is kept beside it."""
    with pytest.raises(studies.RunFailed) as failed:
        studies.run_scene(studies.CASES / "taylor_green.toml", tmp_path / "bad", sets=SETS + ["bogus.key=1"])
    assert not isinstance(failed.value, RuntimeError) and failed.value.returncode == 2
    assert str(failed.value).startswith(f"{tmp_path / 'bad'}: bogus") and "unknown key" in str(failed.value)
    assert len(str(failed.value).splitlines()) == 1


def test_a_resumed_study_runs_again_on_other_ranks_scene_or_code(tmp_path, monkeypatch):
    """A run is read back only for the same rank count (its wall times), scene file contents and psph source;
    a table made from runs of other source (only_finished) says so in its note."""
    scene = tmp_path / "tg.toml"
    scene.write_text((studies.CASES / "taylor_green.toml").read_text())
    done = studies.run_scene(scene, tmp_path / "done", sets=SETS, reuse=True)

    def no_run(*args, **kwargs):
        raise AssertionError("the run was made again")

    monkeypatch.setattr(subprocess, "run", no_run)
    path = tmp_path / "done" / "study_command.json"
    stamp = json.loads(path.read_text())
    assert studies.run_scene(scene, tmp_path / "done", sets=SETS, reuse=True).summary == done.summary
    with pytest.raises(AssertionError, match="made again"):
        studies.run_scene(scene, tmp_path / "done", sets=SETS, reuse=True, ranks=2)
    path.write_text(json.dumps(stamp))  # (the attempt removed it: its run would replace the old one)
    scene.write_text(scene.read_text().replace("t_end", "# a changed scene\nt_end", 1))
    with pytest.raises(AssertionError, match="made again"):
        studies.run_scene(scene, tmp_path / "done", sets=SETS, reuse=True)
    scene.write_text((studies.CASES / "taylor_green.toml").read_text())
    path.write_text(json.dumps({**stamp, "code": "older", "study": "x.py"}))
    with pytest.raises(AssertionError, match="made again"):
        studies.run_scene(scene, tmp_path / "done", sets=SETS, reuse=True)
    path.write_text(json.dumps({**stamp, "code": "older", "study": "x.py"}))
    monkeypatch.setattr(studies, "_STALE_RUNS", [])
    assert studies.run_scene(scene, tmp_path / "done", sets=SETS, only_finished=True).summary == done.summary
    text = studies.write_table(tmp_path / "t", ["a"], [[float("nan")], [None]], note="A note.")
    assert "| nan |" in text and "| - |" in text
    assert f"Read back from runs of other psph source: {tmp_path / 'done'} (x.py)." in text
    assert "Command: " in text
    path.write_text(json.dumps(stamp["command"]))  # an older psph's stamp: the bare command
    with pytest.raises(AssertionError, match="made again"):
        studies.run_scene(scene, tmp_path / "done", sets=SETS, reuse=True)
    path.write_text(json.dumps(stamp["command"]))
    assert studies.run_scene(scene, tmp_path / "done", sets=SETS, only_finished=True).summary == done.summary
    assert f"{tmp_path / 'done'} (an unrecorded command)" in "".join(studies._STALE_RUNS)


def test_a_study_ends_a_refused_run_in_one_line_and_a_nonzero_exit(tmp_path):
    script = studies.CASES.parent / "run_scripts" / "tgv_tradeoff.py"
    res = subprocess.run([sys.executable, str(script), "--resolutions", "0.1", "--methods", "no shifting",
                          "--out", str(tmp_path), "--set", "bogus.key=1"], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert res.stderr.startswith("tgv_tradeoff.py: error: ") and "bogus" in res.stderr
    assert not (tmp_path / "convergence.md").exists()  # no table of "-" made of a refused run


def test_the_stop_message_is_psphs_line_not_mpiexecs_banner():
    err = RuntimeError("mpiexec -n 2 python -m psph run scene.toml failed:\n"
                       "psph: error: IIPS Newton iteration diverged [step 168, t = 0.115]\n"
                       "-----\nPrimary job  terminated normally, but 1 process returned\n-----\n")
    assert studies.stop_message(err) == "psph: error: IIPS Newton iteration diverged [step 168, t = 0.115]"
    assert studies.stop_message(RuntimeError("no psph line\nlast line\n")) == "last line"


def test_the_dominant_frequency_of_an_unevenly_sampled_noisy_oscillation():
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0.0, 50.0, 1800))  # history rows: every 20 steps of a varying dt
    f = 0.2137
    lift = 0.6 + 0.3 * np.sin(2 * np.pi * f * t) + 0.05 * t / 50 + 0.1 * rng.standard_normal(t.size)
    lift[t < 10] = np.exp(-t[t < 10])  # a start-up transient, left out by t0
    assert studies.dominant_frequency(t, lift, t0=25.0) == pytest.approx(f, rel=0.01)
    assert studies.dominant_frequency(t, 2 * np.sin(2 * np.pi * 0.5 * t), t0=25.0) == pytest.approx(0.5, rel=0.01)
    assert np.isnan(studies.dominant_frequency(t, np.full(t.size, 0.6), t0=25.0))  # no oscillation
    assert np.isnan(studies.dominant_frequency(t[:5], lift[:5]))
    assert np.isnan(studies.dominant_frequency(t, lift, t0=40.0))  # two periods are no steady oscillation


@pytest.mark.parametrize("variable", studies.LAUNCHER_RANK_VARIABLES)
def test_a_bad_argument_under_mpiexec_is_printed_by_rank_0_only(monkeypatch, capsys, variable):
    """A benchmark run as `mpiexec -n 2 python run_scripts/bench_iips.py --bad` printed its line once per rank;
    every rank still exits 2."""
    parser = studies.one_line_errors(argparse.ArgumentParser(prog="bench.py"))
    for other in studies.LAUNCHER_RANK_VARIABLES:  # (the test itself may run under mpiexec)
        monkeypatch.delenv(other, raising=False)
    for rank, printed in (("1", ""), ("0", "bench.py: error: unrecognized arguments: --bad\n")):
        monkeypatch.setenv(variable, rank)
        with pytest.raises(SystemExit) as info:
            parser.parse_args(["--bad"])
        assert info.value.code == 2 and capsys.readouterr().err == printed


def test_a_tables_command_line_is_the_study_as_typed(monkeypatch):
    monkeypatch.setattr("sys.argv", ["/work/run_scripts/cavity.py", "--re", "1000", "--set", "iips.update=nfts",
                                     "--out", "results/a b"])
    assert studies.command_line() == "run_scripts/cavity.py --re 1000 --set iips.update=nfts --out 'results/a b'"


def study_module(name="cavity"):
    """run_scripts/NAME.py as a module."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(f"{name}_study", studies.CASES.parent / "run_scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("argv, expected", [
    ([], 2.0),                                     # the scene's h/dx, passed explicitly (earlier runs' key)
    (["--h-over-dx", "1.5"], 1.5),
    (["--set", "domain.h_over_dx=1.5"], 1.5),      # a --set comes last and wins, in the run and the sampling
    (["--walls", "ghost"], 2.0),
])
def test_the_cavity_study_samples_with_the_kernel_of_its_runs(tmp_path, monkeypatch, argv, expected):
    """run_scripts/cavity.py interpolates the centrelines with the h/dx its run used."""
    cavity = study_module()
    seen = {}

    def fake_run(scene, out, sets, ranks, settable=()):
        assert scene == studies.CAVITY and settable == ("domain.h_over_dx",)  # (a --set of it is sampled with)
        seen["sets"] = sets
        return None

    class Sampled(Exception):
        pass

    def fake_centrelines(run, ratio, dx):
        seen["ratio"] = ratio
        raise Sampled

    monkeypatch.setattr(cavity, "run_scene", fake_run)
    monkeypatch.setattr(cavity, "centrelines", fake_centrelines)
    monkeypatch.setattr("sys.argv", ["cavity.py", "--resolutions", "10", "--out", str(tmp_path), *argv])
    with pytest.raises(Sampled):
        cavity.main()
    assert seen["ratio"] == expected
    assert seen["sets"][1] == f"domain.h_over_dx={1.5 if '--h-over-dx' in argv else 2.0}"
    # the wall model is an override of the scene's box, not a scene copy written into the results; the clone
    # walls keep the scene's IIPS + NFTS, the ghost walls (seed 001's) shift with delta+
    # a --set of the study's command line follows every run's own overrides (run_scene adds it)
    every = [value for key, value in zip(argv, argv[1:]) if key == "--set"]
    assert studies._EVERY_RUN["sets"] == every
    scene = load_scene(studies.CAVITY, [*seen["sets"], *every])
    assert scene.bodies[0].model == ("ghost" if "ghost" in argv else "clone")
    assert studies.shifting_label(scene) == ("delta_plus" if "ghost" in argv else "iips + nfts")
    assert not list(tmp_path.glob("*.toml"))


def test_histories_are_written_as_data(tmp_path):
    """write_histories: one CSV line per history row of each run, its labels first."""
    first = [{"time": 0.0, "x": 1.0, "y": 5.0}, {"time": 0.5, "x": 2.0, "y": 6.0}]
    runs = [(("a", 1), studies.Run(tmp_path, {}, first)),
            (("b", 2), studies.Run(tmp_path, {}, [{"time": 0.0, "x": 3.0, "y": 7.0}]))]
    studies.write_histories(tmp_path / "h.csv", ["name", "n"], runs, ["x"])
    lines = (tmp_path / "h.csv").read_text().splitlines()
    assert lines == ["name,n,time,x", "a,1,0.0,1.0", "a,1,0.5,2.0", "b,2,0.0,3.0"]


def test_the_cavity_study_measures_how_steady_the_flow_is():
    """kinetic_energy_change: KE(t_end) / KE(t1) - 1 with t1 the last row at or before 0.8 t_end."""
    cavity = study_module()
    rows = [{"time": t, "kinetic_energy": 1.0 + 0.01 * t} for t in np.linspace(0.0, 10.0, 11)]
    assert cavity.kinetic_energy_change(rows) == pytest.approx(1.10 / 1.08 - 1.0)
    rows = [{"time": t, "kinetic_energy": 2.0} for t in (0.0, 4.0, 7.9, 8.5, 10.0)]
    assert cavity.kinetic_energy_change(rows) == 0.0


def test_the_cavity_study_refuses_a_setting_a_wall_model_cannot_take(tmp_path, monkeypatch, capsys):
    """IIPS needs clone walls: --walls clone ghost --set shifting.method=iips stops with the scene's one-line
    error before the first run, not after the clone-wall runs."""
    cavity = study_module()

    def no_run(*args, **kwargs):
        raise AssertionError("a run started")

    monkeypatch.setattr(cavity, "run_scene", no_run)
    monkeypatch.setattr("sys.argv", ["cavity.py", "--walls", "clone", "ghost", "--set", "shifting.method=iips",
                                     "--out", str(tmp_path / "out")])
    with pytest.raises(SystemExit) as info:
        cavity.main()
    assert info.value.code == 2
    assert "ghost walls: bodies[0].model:" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_shepard_sample_reproduces_a_linear_field_inside_and_is_nan_outside():
    """psph.studies.shepard_sample (on diagnostics.shepard_sums): on a full lattice the Shepard interpolation
    of a linear field is exact at a probe whose support is symmetric; a probe no particle reaches gives nan."""
    from psph.compute.smoothing import make_kernel
    from psph.studies import shepard_sample

    kernel = make_kernel("wendland_c6", 2, 0.1)
    grid = np.stack(np.meshgrid(np.arange(20) * 0.05, np.arange(20) * 0.05, indexing="ij"), -1).reshape(-1, 2)
    values = np.stack([2.0 * grid[:, 0] + 1.0, grid[:, 1]], axis=1)
    out = shepard_sample(grid, np.full(len(grid), 0.0025), values, np.array([[0.5, 0.5], [5.0, 5.0]]), kernel)
    assert np.allclose(out[0], [2.0, 0.5], atol=1e-12)
    assert np.isnan(out[1]).all()


def test_spot_noise_is_zero_for_a_linear_field_and_measures_spots():
    """run_scripts/dam_break_long.py's measure of seed 001's spots: a plane, also at the lattice's edges, gives
    round-off; a checkerboard of amplitude a on top of it gives 0.75 a; random spots 0.88 of their RMS (a
    particle's own value takes part in its fit). The radius, 2.1 spacings, keeps round-off from deciding
    which neighbours at 2 spacings count."""
    x, y = np.meshgrid(np.arange(20) * 0.05, np.arange(8) * 0.05)
    pos = np.stack([x.ravel(), y.ravel()], axis=1)
    plane = 0.4 - pos[:, 1] + 0.3 * pos[:, 0]
    assert studies.spot_noise(pos, plane, 0.105) < 1e-13
    checker = np.where((np.rint(x / 0.05) + np.rint(y / 0.05)).ravel() % 2 == 0, 1.0, -1.0)
    assert studies.spot_noise(pos, plane + 0.01 * checker, 0.105) / 0.01 == pytest.approx(0.753, abs=0.01)
    spots = np.random.default_rng(0).standard_normal(len(pos))
    assert studies.spot_noise(pos, 1e-3 * spots, 0.105) / 1e-3 == pytest.approx(0.88, abs=0.02)


def test_the_long_dam_break_study_tables_finished_and_stopped_runs(tmp_path, monkeypatch):
    """run_scripts/dam_break_long.py end to end at H/dx = 5 to t = 0.1 (its standard SPH run made to stop, as
    it does at t = 6-8): a row of measures per finished run, the stop's message in one cell of its row, and
    the figure."""
    study = study_module("dam_break_long")
    real = study.run_scene

    def run_scene(scene, out, sets=(), **kwargs):
        if "physics.delta=0" in sets:  # a diagnosed stop, as studies.run_scene leaves it
            message = ("psph ... failed:\npsph: error: density left the weakly compressible range: "
                       "|rho/rho0 - 1| = 0.58 > 0.5 [step 9, t = 0.01]")
            out.mkdir(parents=True)
            (out / "study_stopped.txt").write_text(message)
            raise studies.RunStopped(message)
        return real(scene, out, sets=sets, **kwargs)

    monkeypatch.setattr(study, "run_scene", run_scene)
    monkeypatch.setattr("sys.argv", ["dam_break_long.py", "--resolutions", "5", "--t-end", "0.1", "--out",
                                     str(tmp_path)])
    study.main()
    lines = (tmp_path / "long.md").read_text().splitlines()
    rows = {line.split(" | ")[0].removeprefix("| "): line for line in lines if line.startswith("| ")}
    assert set(rows) == {"scheme", "delta-ALE-SPH", "standard SPH", "Lagrangian delta-SPH"}
    columns = rows["scheme"].count(" | ")
    assert all(row.replace("\\|", "").count(" | ") == columns for row in rows.values())
    assert "stopped: density left the weakly compressible range: \\|rho/rho0 - 1\\| = 0.58" in rows["standard SPH"]
    assert "stopped: density left the weakly compressible range: |rho/rho0 - 1| = 0.58" in \
        (tmp_path / "long.csv").read_text()  # escaped for Markdown only
    for scheme in ("delta-ALE-SPH", "Lagrangian delta-SPH"):
        cells = rows[scheme].strip("| ").split(" | ")
        assert int(cells[2]) > 50 and all(np.isfinite(float(c)) for c in cells[3:])
    assert (tmp_path / "long.png").stat().st_size > 10_000


def test_the_volume_budget_adds_up_to_the_measured_volume_change(tmp_path, monkeypatch):
    """run_scripts/volume_budget.py end to end (clone walls, dx = 0.1, t = 0.1..0.2): its parts, one evaluation per
    step, add up to the change of the total volume it measures (4% apart here: a left Riemann sum)."""
    study = study_module("volume_budget")
    monkeypatch.setattr("sys.argv", ["volume_budget.py", "--walls", "clone", "--dx", "0.1", "--t0", "0.1", "--t1",
                                     "0.2", "--out", str(tmp_path)])
    study.main()
    with open(tmp_path / "budget.csv", newline="") as f:
        rows = {row[1]: row for row in csv.reader(f)}
    parts, measured = float(rows["sum of the parts"][-1]), float(rows["eps_V(0.2) - eps_V(0.1)"][-1])
    assert measured != 0.0 and parts == pytest.approx(measured, rel=0.15)


def test_the_volume_budget_takes_petsc_options_and_reports_a_bad_one_in_a_line(tmp_path):
    script = studies.CASES.parent / "run_scripts" / "volume_budget.py"
    res = subprocess.run([sys.executable, str(script), "--walls", "clone", "--dx", "0.1", "--t0", "0.1", "--t1", "0.2",
                          "--out", str(tmp_path), "--set", "shifting.method=iips", "-iips_pc_type", "nonexistent"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 1
    assert res.stderr.strip().splitlines() == [res.stderr.strip()]
    assert "clone walls" in res.stderr and "Unable to find requested PC type nonexistent" in res.stderr


def test_the_volume_budget_refuses_a_scene_too_large_unless_allowed(tmp_path, monkeypatch, capsys):
    """It builds its runs itself (not through psph run): its --allow-large did nothing, and a dx of 2e-4 (25
    million particles) or a t1 of 1e9 (7e11 steps) started a run that could not end."""
    study = study_module("volume_budget")
    for arg, value, key in (("--dx", "0.0002", "domain.dx"), ("--t1", "1e9", "time.t_end")):
        monkeypatch.setattr("sys.argv", ["volume_budget.py", "--walls", "clone", arg, value, "--out", str(tmp_path)])
        with pytest.raises(SystemExit) as info:
            study.main()
        err = capsys.readouterr().err
        assert info.value.code == 2 and f"clone walls: {key}:" in err and "--allow-large" in err
        assert not (tmp_path / "run_clone").exists()


def run_main(study, capsys):
    """study.main() as run_study runs it: (exit code, stderr)."""
    with pytest.raises(SystemExit) as info:
        studies.run_study(study.main)
        raise SystemExit(0)
    return info.value.code, capsys.readouterr().err


def test_a_table_without_a_measured_row_is_not_written_and_the_old_one_is_kept(tmp_path):
    """A study audit: a failed or empty sweep (no row, or nothing but "-" past the labels) replaced the tables of
    an earlier one with empty ones."""
    studies.write_table(tmp_path / "t", ["method", "error"], [["IIPS", 0.5]])
    old = (tmp_path / "t.md").read_text(), (tmp_path / "t.csv").read_text()
    for rows, labels in (([], 1), ([["IIPS", None], ["delta+", "-"]], 1), ([[0.1, "IIPS", ""]], 2)):
        with pytest.raises(studies.NothingMeasured, match=r"t\.md not written: no row of it was measured; the files "
                                                          r"there are kept$"):
            studies.write_table(tmp_path / "t", ["dx", "method", "error"][-len(rows[0]) if rows else 1:], rows,
                                labels=labels)
        assert ((tmp_path / "t.md").read_text(), (tmp_path / "t.csv").read_text()) == old
    # a row whose only cells are labels is a table (one resolution: no rate), and a stop's message a result
    studies.write_table(tmp_path / "u", ["h/dx"], [[2.0]])
    studies.write_table(tmp_path / "u", ["method", "error"], [["IIPS", "stopped: NaN"], ["delta+", None]])


def test_a_stability_map_keeps_the_finished_map_when_its_first_case_is_refused(tmp_path, monkeypatch, capsys):
    """A study audit: a refused first case (e.g. a value psph refuses) replaced the finished map with an empty
    one, and the finally block's table could hide the refusal's message."""
    study = study_module("stability_map")
    (tmp_path / "map.md").write_text("the finished map\n")

    def refused(scene, out, sets):
        raise studies.RunFailed(f"{out}: physics.sound_speed: must be > 0", 2)

    monkeypatch.setattr(study, "run_scene", refused)
    monkeypatch.setattr("sys.argv", ["stability_map.py", "--dx", "0.1", "--sigmas", "0", "--ratios", "2", "--c0", "5",
                                     "--reynolds", "10", "--methods", "none", "--out", str(tmp_path)])
    code, err = run_main(study, capsys)
    assert code == 2 and err.strip().endswith("physics.sound_speed: must be > 0") and len(err.splitlines()) == 1, err
    assert (tmp_path / "map.md").read_text() == "the finished map\n" and not (tmp_path / "map.csv").exists()


def test_a_stability_map_keeps_the_finished_map_when_a_later_case_refuses_its_set(tmp_path, monkeypatch, capsys):
    """A review: `--set iips.threshold=0.01` ran the "none" cases, was refused at the first IIPS case (which
    sets the key itself), and the finally block replaced the finished map with the one case run."""
    study = study_module("stability_map")
    (tmp_path / "map.md").write_text("the finished map\n")
    calls = []

    def run(scene, out, sets):
        calls.append(out)
        studies.study_command(scene, out, sets)  # the clash check of every run
        raise AssertionError("a case ran past the check") if len(calls) > 1 else studies.RunStopped("stopped")

    monkeypatch.setattr(study, "run_scene", run)
    monkeypatch.setattr("sys.argv", ["stability_map.py", "--dx", "0.1", "--sigmas", "0", "--ratios", "2", "--c0", "5",
                                     "--reynolds", "10", "--methods", "none", "iips", "--set", "iips.threshold=0.01",
                                     "--out", str(tmp_path)])
    code, err = run_main(study, capsys)
    assert code == 2 and "--set iips.threshold=0.01: this study sets iips.threshold on its runs itself" in err, err
    assert len(calls) == 2 and (tmp_path / "map.md").read_text() == "the finished map\n"


def test_no_run_with_no_finished_run_says_so_and_keeps_the_tables(tmp_path):
    """A study audit: --no-run with no finished run in --out replaced the tables with empty ones and exited 0."""
    script = studies.CASES.parent / "run_scripts" / "tgv_tradeoff.py"
    (tmp_path / "convergence.md").write_text("old\n")
    res = subprocess.run([sys.executable, str(script), "--resolutions", "0.05", "0.025", "--methods", "IIPS",
                          "--no-run", "--out", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 2 and res.stderr.strip().splitlines() == [
        f"tgv_tradeoff.py: error: {tmp_path / 'convergence.md'} not written: found no finished run in --out {tmp_path} "
        "(--no-run); the files there are kept"], res.stderr
    assert (tmp_path / "convergence.md").read_text() == "old\n" and not (tmp_path / "tradeoff.md").exists()


def test_a_study_keeps_the_results_of_other_arguments_unless_told_to_overwrite(tmp_path, monkeypatch, capsys):
    """A scripts audit: a second study into the same --out (iips_static.py --resolutions 0.1 after
    --resolutions 0.1 0.0625) replaced the first one's runs and tables without a word."""
    def parse(*argv):
        parser = argparse.ArgumentParser(prog="s.py")
        parser.add_argument("--out", type=Path)
        parser.add_argument("--resolutions", type=float, nargs="+")
        parser.add_argument("--no-run", action="store_true")
        parser.add_argument("--in-progress", action="store_true")  # (ellipse.py's: a review found it refused)
        args = studies.parse_args(parser, ["--out", str(tmp_path), *argv])
        studies.write_table(tmp_path / "table", ["resolutions", "error"], [[str(args.resolutions), 0.1]])

    monkeypatch.setattr("sys.argv", ["run_scripts/s.py"])
    with pytest.raises(SystemExit):  # refused before it wrote anything: no stamp, no claim
        parse("--resolutions", "0.1", "0.1")
    assert "0.1 given twice" in capsys.readouterr().err and not tmp_path.joinpath(studies.STUDY_STAMP).exists()
    parse("--resolutions", "0.1", "0.05")
    parse("--resolutions", "0.1", "0.05", "--no-run")  # the same arguments again, or their tables again
    parse("--resolutions", "0.1", "0.05", "--in-progress")
    with pytest.raises(SystemExit) as info:
        parse("--resolutions", "0.1")
    assert info.value.code == 2 and capsys.readouterr().err == (
        f"s.py: error: argument --out: {tmp_path} holds the results of other arguments (resolutions [0.1, 0.05] "
        "-> [0.1]); give --overwrite to replace them, or another --out\n")
    with pytest.raises(SystemExit):
        parse("--resolutions", "0.1", "0.05", "--set", "domain.kernel=quintic_spline")
    assert "set [] -> ['domain.kernel=quintic_spline']" in capsys.readouterr().err
    parse("--resolutions", "0.1", "--overwrite")  # replaces them, and is the stamp now
    monkeypatch.setattr("sys.argv", ["run_scripts/t.py"])
    with pytest.raises(SystemExit):
        parse("--resolutions", "0.1")
    assert "holds the results of s.py; give --overwrite" in capsys.readouterr().err


def fake_static_run(errors, iterations=10):
    """run_scene for iips_static.py: a run whose L2(df/dx) is errors[dx] after `iterations` Newton iterations."""
    def run_scene(scene, out, ranks, sets):
        dx = float(next(s for s in sets if s.startswith("domain.dx=")).split("=")[1])
        history = [{"iteration": k, "L2_grad_c": 1.0 / (k + 1), "L2_dfdx": errors[dx] * (2.0 if k == 0 else 1.0),
                    "L2_dfdx_cartesian": 0.5 * errors[dx]} for k in range(iterations + 1)]
        return studies.Run(out, {"n_particles": round(1 / dx**2)}, history)
    return run_scene


def test_the_static_study_rates_by_the_resolutions_ratio(tmp_path, monkeypatch):
    """A study audit: Table 8.1's rate assumed dx halves (1.14 for the 1.68 of dx = 0.1 to 0.0625)."""
    import math

    study = study_module("iips_static")
    monkeypatch.setattr(study, "run_scene", fake_static_run({0.1: 3.77, 0.0625: 1.71}))
    monkeypatch.setattr("sys.argv", ["iips_static.py", "--resolutions", "0.1", "0.0625", "--ratios", "2.0",
                                     "--out", str(tmp_path)])
    study.main()
    rates = [row.split(",")[2] for row in (tmp_path / "table_8_1.csv").read_text().splitlines()[1:]]
    assert rates[0] == "nan" and float(rates[1]) == pytest.approx(math.log(3.77 / 1.71) / math.log(0.1 / 0.0625))


def test_the_static_study_tables_a_history_shorter_than_five_iterations(tmp_path, monkeypatch):
    """A study audit: IIPS stopping before iteration 5 (a lattice it leaves alone, a large iips.threshold) ended
    the study in an IndexError; what was not reached is "-"."""
    study = study_module("iips_static")
    monkeypatch.setattr(study, "run_scene", fake_static_run({0.1: 3.77}, iterations=2))
    monkeypatch.setattr("sys.argv", ["iips_static.py", "--resolutions", "0.1", "--ratios", "2.0", "--out",
                                     str(tmp_path)])
    study.main()
    with open(tmp_path / "histories.csv", newline="") as f:
        header, *rows = list(csv.reader(f))
    assert len(rows) == 2 and all(row[header.index("L2(gradC) it 5")] == "" for row in rows)
    assert all(row[header.index("drop at it 5")] == "" and row[header.index("at it")] == "2" for row in rows)
    assert "| - | - |" in (tmp_path / "histories.md").read_text()


def test_a_study_refuses_a_set_of_a_key_it_sweeps_before_any_run(tmp_path, monkeypatch, capsys):
    """A study audit: --set domain.dx=0.05 in iips_static.py ran at dx = 0.05 and labelled the row dx = 0.1."""
    study = study_module("iips_static")
    monkeypatch.setattr(subprocess, "run", lambda *a, **k: pytest.fail("a run started"))
    monkeypatch.setattr("sys.argv", ["iips_static.py", "--resolutions", "0.1", "--ratios", "2.0", "--set",
                                     "domain.dx=0.05", "--out", str(tmp_path)])
    code, err = run_main(study, capsys)
    assert code == 2 and err == ("iips_static.py: error: --set domain.dx=0.05: this study sets domain.dx on its runs "
                                 f"itself (domain.dx=0.1 in {tmp_path / 'dx0.1_s0.1'}), and its tables say so; change "
                                 "it with the study's own options\n")
    assert not list(tmp_path.iterdir())


def test_the_operator_study_refuses_a_kernel_support_as_large_as_the_periodic_box():
    """A study audit: the 3 x 3 tiling of a unit box that the support covers tabled a grad p error of 3e12."""
    lattice = (np.stack(np.meshgrid(*[(np.arange(2) + 0.5) / 2] * 2, indexing="ij"), -1).reshape(-1, 2))
    with pytest.raises(studies.UsageError, match=r"^h/dx = 2 on 4 particles \(dx = 0.5\): the kernel support 2 "
                                                 r"is not smaller than the periodic unit box"):
        studies.tgv_operator_errors(lattice, np.full(4, 0.25), 2.0)
    with pytest.raises(studies.UsageError, match=r"^h/dx = nan: must be within 1 and 4"):
        studies.unit_box_kernel(100, float("nan"))
    assert studies.unit_box_kernel(100, 2.0).support == pytest.approx(0.4)


def test_run_study_exit_codes_a_stop_a_crash_and_bad_input(tmp_path, monkeypatch, capsys):
    """A study audit: a NumericalError of an in-process benchmark exited 2 (bad input), not 3; a crashed run
    exited 2 with psph's "internal error" line only, not saying where its traceback was."""
    from psph.errors import NumericalError, SceneError

    class Study:
        def __init__(self, err):
            self.err = err

        def main(self):
            raise self.err

    code, err = run_main(Study(NumericalError("density left the range", step=3)), capsys)
    assert code == 3 and err.endswith("error: density left the range [step 3]\n")
    code, err = run_main(Study(SceneError("domain.dx", "must be > 0")), capsys)
    assert code == 2 and err.endswith("error: domain.dx: must be > 0\n")
    crash = ("Traceback (most recent call last):\n  File x, line 1\nImportError: cannot import name 'GAMMA' from "
             "'psph.schemes.eos'\npsph: internal error on rank 0 (a bug; please report it)\n")
    monkeypatch.setattr(subprocess, "run", lambda *a, **k: subprocess.CompletedProcess(a, 1, "", crash))
    (tmp_path / "run").mkdir()
    with pytest.raises(studies.RunFailed) as failed:
        studies.run_scene(studies.CASES / "taylor_green.toml", tmp_path / "run", sets=SETS)
    code, err = run_main(Study(failed.value), capsys)
    assert code == 1 and err.splitlines() == [
        f"{Path(sys.argv[0]).name}: error: {tmp_path / 'run'}: psph: internal error on rank 0 (a bug; please report "
        "it) (ImportError: cannot import name 'GAMMA' from 'psph.schemes.eos'); its stderr is in "
        f"{tmp_path / 'run' / 'study_failed.txt'}"]
    assert "Traceback" in (tmp_path / "run" / "study_failed.txt").read_text()


def test_a_study_passes_allow_large_to_every_run():
    """A study audit: psph's advice "(run with --allow-large to try anyway)" named an option no study took."""

    args = studies.parse_args(argparse.ArgumentParser(), ["--allow-large"])
    assert args.allow_large and "--allow-large" in studies.study_command("s.toml", "out", sets=["domain.dx=0.1"])
    studies.parse_args(argparse.ArgumentParser(), [])
    assert "--allow-large" not in studies.study_command("s.toml", "out")
