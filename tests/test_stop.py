"""Stopping on a signal (psph.stop): SIGTERM, SIGINT or SIGUSR1 ends the step in progress, writes a
checkpoint and exits with 128 + the signal's number; the restart equals the run that was never stopped.
The signal is sent by the run itself at a chosen step (deterministic, unlike a timer)."""

import subprocess
import sys
import textwrap

import h5py
import pytest

from psph.io.checkpoint import latest_checkpoint
from psph.io.history import read_history
from psph.io.snapshots import snapshot_files
from tests.helpers import CASES, ROOT, mpi_environment, run_psph
from tests.io.test_checkpoint import TIMING

FLUID = [CASES / "taylor_green.toml", "--set", "domain.dx=0.05", "--set", "time.t_end=0.06"]
KINEMATIC = [CASES / "kinematic_tgv.toml", "--set", "domain.dx=0.05", "--set", "time.t_end=0.05", "--set",
             "iips.pre_newton=5", "--set", "iips.beta=5", "--set", "output.every=0"]
STATIC = [CASES / "static_perturbed.toml", "--set", "domain.dx=0.05", "--set", "shifting.method=iips"]


def signalling_script(argv, signame, at, rank=0, times=1, static=False):
    """A `psph run` that sends itself `signame` `times` times at step `at` (Newton iteration `at` of a
    static run), on rank `rank` only."""
    if static:  # the static driver measures the lattice, the start, then each iteration
        hook = f"""
            import psph.drivers.static as target
            original = target.distribution_report
            calls = []
            def hooked(*args):
                calls.append(1)
                if len(calls) == {at} + 2:
                    send()
                return original(*args)
            target.distribution_report = hooked
            """
    else:  # every time-dependent step asks whether a checkpoint is due
        hook = f"""
            from psph.simulation import Simulation as target
            original = target.checkpoint_due
            def hooked(self, step, last):
                if step == {at}:
                    send()
                return original(self, step, last)
            target.checkpoint_due = hooked
            """
    return textwrap.dedent(f"""
        import os, signal, sys
        from mpi4py import MPI
        from psph.cli import main
        def send():
            if MPI.COMM_WORLD.rank == {rank}:
                for _ in range({times}):
                    os.kill(os.getpid(), signal.{signame})
        """) + textwrap.dedent(hook) + f"\nsys.exit(main({[str(a) for a in argv]!r}))\n"


def run_signalling(tmp_path, argv, signame, at, ranks=1, **kw):
    script = tmp_path / "signalling.py"
    script.write_text(signalling_script(argv, signame, at, **kw))
    cmd = [sys.executable, str(script)]
    if ranks > 1:
        cmd = ["mpiexec", "-n", str(ranks), "--oversubscribe"] + cmd
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT, env=mpi_environment())


def same_history(a, b):
    """The histories of a stopped-and-continued run and of the whole run: the same rows, values equal to
    round-off (the checkpoint rebuilds the neighbour lists, which reorders the sums), KSP iteration
    counts aside (a tolerance at round-off level makes them vary)."""
    rows_a, rows_b = read_history(a / "history.csv"), read_history(b / "history.csv")
    assert [r.get("step") for r in rows_a] == [r.get("step") for r in rows_b]
    for ra, rb in zip(rows_a, rows_b):
        for key in ra.keys() - set(TIMING) - {"iips_linear", "ksp_iterations", "linear_iterations"}:
            assert ra[key] == pytest.approx(rb[key], rel=1e-9, abs=1e-12), key


def snapshot_steps(out):
    steps = []
    for path in snapshot_files(out):
        with h5py.File(path, "r") as f:
            steps.append(int(f.attrs["step"]))
    return steps


def last_line(stderr):
    return [line for line in stderr.splitlines() if line.strip()][-1]


@pytest.mark.parametrize("case", ["fluid", "kinematic"])
def test_sigterm_stops_after_the_step_with_a_checkpoint_the_restart_equals_the_whole_run(tmp_path, case):
    args = {"fluid": FLUID, "kinematic": KINEMATIC}[case]
    tight = ["-iips_ksp_rtol", "1e-12", "-iips_ksp_atol", "1e-30"]  # IIPS solves to round-off: sums reordered
    out = tmp_path / "stopped"
    done = run_signalling(tmp_path, ["run", *args, "--out", out, *tight], "SIGTERM", at=6)
    assert done.returncode == 128 + 15, done.stderr
    assert "Traceback" not in done.stderr
    checkpoint = out / "checkpoint_000006.h5"
    assert "psph: SIGTERM received: stopping after this step with a checkpoint (send it again" in done.stderr
    assert last_line(done.stderr).startswith("psph: stopped by SIGTERM: state at step 6, t = ")
    shown = snapshot_files(out)[-1]  # the stopped state, to look at (output.every has not come round)
    assert last_line(done.stderr).endswith(f"saved in {checkpoint} and {shown}; continue with: psph run "
                                           f"--restart {checkpoint}")
    assert snapshot_steps(out)[-1] == 6 and 6 not in snapshot_steps(out)[:-1]
    assert 'Name="step_6"' in (out / "psph.xdmf").read_text()
    assert [p.name for p in out.glob("checkpoint_*")] == [checkpoint.name]
    assert (out / "psph.log").read_text().splitlines()[-1] == last_line(done.stderr)
    assert run_psph("run", "--restart", checkpoint, *tight).returncode == 0
    whole = run_psph("run", *args, "--out", tmp_path / "whole", *tight)
    assert whole.returncode == 0, whole.stderr
    same_history(out, tmp_path / "whole")
    # the continuation wrote its snapshots over the stopped state's, as the run never stopped did
    assert snapshot_steps(out) == snapshot_steps(tmp_path / "whole")
    assert 6 not in snapshot_steps(out)


def test_a_stop_on_a_checkpoint_step_writes_it_once(tmp_path):
    out = tmp_path / "stopped"
    done = run_signalling(tmp_path, ["run", *FLUID, "--out", out, "--checkpoint-every", "3"], "SIGTERM", at=6)
    assert done.returncode == 128 + 15, done.stderr
    assert [p.name for p in out.glob("checkpoint_*")] == ["checkpoint_000006.h5"]
    assert (out / "psph.log").read_text().count("checkpoint checkpoint_000006.h5") == 1


def test_a_signal_on_one_rank_stops_every_rank_after_the_same_step(tmp_path):
    """SIGUSR1 (what mpiexec forwards to the ranks) reaching rank 1 only: both ranks stop after step 6,
    and the 2-rank restart equals the 2-rank run that was never stopped."""
    out = tmp_path / "stopped"
    done = run_signalling(tmp_path, ["run", *FLUID, "--out", out], "SIGUSR1", at=6, ranks=2, rank=1)
    assert done.returncode == 128 + 10, done.stderr
    assert "psph: stopped by SIGUSR1: state at step 6, t = " in done.stderr
    assert [p.name for p in out.glob("checkpoint_*")] == ["checkpoint_000006.h5"]
    assert run_psph("run", "--restart", out / "checkpoint_000006.h5", ranks=2).returncode == 0
    whole = run_psph("run", *FLUID, "--out", tmp_path / "whole", ranks=2)
    assert whole.returncode == 0, whole.stderr
    same_history(out, tmp_path / "whole")


def test_a_second_signal_stops_at_once_keeping_what_was_written(tmp_path):
    out = tmp_path / "stopped"
    done = run_signalling(tmp_path, ["run", *FLUID, "--out", out, "--checkpoint-every", "4"], "SIGINT", at=6,
                          times=2)
    assert done.returncode == 128 + 2, done.stderr
    assert "Traceback" not in done.stderr
    assert last_line(done.stderr) == "psph: stopped at once by SIGINT; nothing saved past the last checkpoint"
    assert [p.name for p in out.glob("checkpoint_*")] == ["checkpoint_000004.h5"]
    assert run_psph("run", "--restart", out / "checkpoint_000004.h5").returncode == 0
    assert read_history(out / "history.csv")[-1]["time"] == pytest.approx(0.06)


def test_sigterm_stops_a_static_run_after_the_iteration(tmp_path):
    out = tmp_path / "stopped"
    done = run_signalling(tmp_path, ["run", *STATIC, "--out", out], "SIGTERM", at=2, static=True)
    assert done.returncode == 128 + 15, done.stderr
    # (it said "stopping after this step with a checkpoint")
    assert "psph: SIGTERM received: stopping after this iteration with a snapshot (send it again" in done.stderr
    assert last_line(done.stderr) == (f"psph: stopped by SIGTERM: the state after iteration 2 is in "
                                      f"{out / 'snapshot_000001.h5'} (static runs write no checkpoint)")
    assert [row["iteration"] for row in read_history(out / "history.csv")] == [0, 1, 2]
    assert latest_checkpoint(out) is None


def test_the_continue_hint_names_the_rank_count():
    """An I/O audit: a 2-rank run was told to continue with a bare `psph run --restart`."""
    from psph.stop import checkpoint_message

    assert checkpoint_message(7, 0.5, "OUT/c.h5", 2).endswith("continue with: mpiexec -n 2 psph run --restart OUT/c.h5")
    assert checkpoint_message(7, 0.5, "OUT/c.h5").endswith("continue with: psph run --restart OUT/c.h5")
