"""Drivers end to end through the command line: static IIPS history, kinematic Procedures A, B and C."""

import json
import re

import h5py
import numpy as np
import pytest

from psph.io.history import read_history
from tests.helpers import CASES, run_psph

KINEMATIC = ["--set", "domain.dx=0.05", "--set", "time.t_end=0.02", "--set", "iips.pre_newton=20"]


def test_static_iips_run_writes_one_row_per_newton_iteration(tmp_path):
    out = tmp_path / "out"
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", out, "--set", "shifting.method=iips",
                   "--set", "iips.max_newton=5", "--set", "domain.dx=0.05")
    assert res.returncode == 0, res.stderr
    rows = read_history(out / "history.csv")
    assert [r["iteration"] for r in rows] == [0, 1, 2, 3, 4, 5]
    assert [r["time"] for r in rows] == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]  # the snapshots' time axis
    assert rows[-1]["L2_grad_c"] < 1e-2 * rows[0]["L2_grad_c"]
    assert all(r["ksp_iterations"] > 0 for r in rows[1:])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == 5 and summary["final"]["L2_grad_c"] == rows[-1]["L2_grad_c"]
    with h5py.File(out / "snapshot_000000.h5") as first, h5py.File(out / "snapshot_000001.h5") as last:
        assert last.attrs["step"] == 5 and last.attrs["time"] == 5.0  # a static snapshot's time is its iteration
        assert not np.allclose(first["particles/position"][:], last["particles/position"][:])
    # ParaView reads one time step when both grids say time 0, and shows nothing: the time is the iteration
    times = re.findall(r'<Time Value="([^"]+)"/>', (out / "psph.xdmf").read_text())
    assert [float(t) for t in times] == [0.0, 5.0]


def test_a_static_run_ended_by_backtracking_counts_and_labels_its_accepted_iterations(tmp_path):
    """iips.backtrack = 3 at h/dx = 1.2 (the case of tests/shifting/test_iips.py): the sixth step is undone,
    which ends the run after five iterations: five rows, 5 steps in the summary, the last snapshot labelled
    step 5, and the reason in the log."""
    out = tmp_path / "out"
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", out, "--set", "shifting.method=iips",
                   "--set", "domain.dx=0.0625", "--set", "domain.h_over_dx=1.2", "--set", "initial.seed=3",
                   "--set", "iips.max_newton=15", "--set", "iips.backtrack=3")
    assert res.returncode == 0, res.stderr
    rows = read_history(out / "history.csv")
    assert [r["iteration"] for r in rows] == [0, 1, 2, 3, 4, 5]
    assert json.loads((out / "summary.json").read_text())["steps"] == 5
    with h5py.File(out / "snapshot_000001.h5") as last:
        assert last.attrs["step"] == 5
    assert "IIPS call ended after 6 iterations: no descent in 3 halvings" in (out / "psph.log").read_text()


@pytest.mark.parametrize("procedure", ["A", "B"])
def test_kinematic_iips_procedures(tmp_path, procedure):
    out = tmp_path / procedure
    res = run_psph("run", CASES / "kinematic_tgv.toml", "--out", out, *KINEMATIC,
                   "--set", f"iips.procedure={procedure}", "--set", "iips.on_failure=warn")
    assert res.returncode == 0, res.stderr
    summary = json.loads((out / "summary.json").read_text())
    rows = read_history(out / "history.csv")
    steps = summary["steps"]
    assert steps == 20 and len(rows) == steps + 1 and summary["end_time"] == pytest.approx(0.02)
    # a row is the distribution after a step's shifting, at the time it was applied (before the advection)
    assert [r["time"] for r in rows[:2]] == [0.0, 0.0]
    assert rows[-1]["time"] == summary["final"]["time"] == pytest.approx(0.02 - summary["dt"])
    newton = [r["newton"] for r in rows[1:]]
    if procedure == "A":
        assert min(newton) >= 1
    threshold = summary["threshold"]
    assert threshold == pytest.approx(5.0 * summary["pre_procedure_linf"])
    below = [r["Linf_grad_c"] <= threshold * (1 + 1e-12) for r in rows[1:]]
    assert summary["failed_calls"] == 0 and all(below)  # every step meets the threshold


def test_a_kinematic_run_ends_at_t_end(tmp_path):
    """A drivers audit: with t_end not a multiple of dt the last step overshot t_end (here to 0.021); it is
    shortened, so the run, its last snapshot and its summary end at t_end, and `psph info` says so."""
    args = [*KINEMATIC, "--set", "time.t_end=0.0205"]  # dt = 0.001
    res = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path, *args, "--quiet")
    assert res.returncode == 0, res.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["steps"] == 21 and summary["end_time"] == 0.0205
    with h5py.File(sorted(tmp_path.glob("snapshot_*.h5"))[-1]) as last:
        assert last.attrs["step"] == 21 and last.attrs["time"] == 0.0205
    info = run_psph("info", CASES / "kinematic_tgv.toml", *args)
    assert "21 steps to t = 0.0205 (the last of 0.0005)" in info.stdout, info.stdout


def test_kinematic_explicit_procedure_c_lets_the_distribution_degrade(tmp_path):
    iips, explicit = tmp_path / "iips", tmp_path / "explicit"
    common = ["--set", "domain.dx=0.05", "--set", "time.t_end=0.1", "--set", "iips.pre_newton=20",
              "--set", "output.history_every=50"]
    assert run_psph("run", CASES / "kinematic_tgv.toml", "--out", iips, *common,
                    "--set", "iips.on_failure=warn").returncode == 0
    res = run_psph("run", CASES / "kinematic_tgv.toml", "--out", explicit, *common,
                   "--set", "shifting.method=explicit_iterative", "--set", "shifting.diffusion=0.01")
    assert res.returncode == 0, res.stderr
    linf_iips = read_history(iips / "history.csv")[-1]["Linf_grad_c"]
    linf_expl = read_history(explicit / "history.csv")[-1]["Linf_grad_c"]
    assert linf_expl > 10 * linf_iips
    # Procedure C's snapshots hold no IIPS shift: the temporary pre-procedure's field is not left behind
    # (every snapshot showed its last shift, 0.8 dx, as the run's; an audit)
    for snapshot in sorted(explicit.glob("snapshot_*.h5")):
        with h5py.File(snapshot) as f:
            assert "iips_shift" not in f["particles"] and "grad_c" in f["particles"], snapshot.name
    with h5py.File(sorted(iips.glob("snapshot_*.h5"))[-1]) as f:  # (IIPS's own: its last call's shift)
        assert "iips_shift" in f["particles"]


LAW_RUN = ["--set", "domain.dx=0.05", "--set", "time.t_end=0.2", "--set", "iips.pre_newton=0", "--set", "iips.beta=0",
           "--set", "initial.sigma_over_dx=0", "--set", "output.every=0", "--set", "output.history_every=10"]


def test_explicit_laws_shift_a_kinematic_run(tmp_path):
    """Thesis ch. 7 runs the explicit laws with the analytic field imposed throughout (figs. 7.1, 7.4), which
    psph's kinematic driver could not: the laws needed a fluid scheme. From the lattice at dx = 0.05, the
    frozen Taylor-Green field alone leaves Linf(grad C) at 0.50 and L2(d f/dx) at 1.79 by t = 0.2; every law
    lowers L2(d f/dx) (delta+ 0.44, Lind 0.21, Skillen 1.29, Oger 1.40, Neuhauser P_S = 10 1.18), and the
    two built on grad C^ Linf(grad C) too (0.12, 0.046). `psph info` names the law."""
    final = {}
    for law in ("none", "delta_plus", "lind", "skillen", "oger", "neuhauser"):
        res = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path / law, *LAW_RUN, "--quiet",
                       "--set", f"shifting.method={law}")
        assert res.returncode == 0, res.stderr
        final[law] = read_history(tmp_path / law / "history.csv")[-1]
    for law in final:  # (Oger's 0.78 of none's: no tighter bound, a test audit)
        if law != "none":
            assert final[law]["L2_dfdx"] < 0.9 * final["none"]["L2_dfdx"], law
    for law in ("delta_plus", "lind"):
        assert final[law]["Linf_grad_c"] < 0.3 * final["none"]["Linf_grad_c"], law
    info = run_psph("info", CASES / "kinematic_tgv.toml", *LAW_RUN, "--set", "shifting.method=neuhauser")
    assert "shifting: Neuhauser Riemann-based transport-velocity correction with P_S = 10" in info.stdout, info.stdout


@pytest.mark.parametrize("law, key", [("skillen", "shifting.skillen_a = 1e+06"),
                                      ("neuhauser", "shifting.neuhauser_ps = 1e+06")])
def test_a_kinematic_law_faster_than_sound_stops_naming_its_strength(tmp_path, law, key):
    """A failure audit: with skillen_a = 1e6 the law threw the particles 8-10 dx a step, at random through
    the box, and the run ended with exit 0 (neuhauser_ps alike); a fluid run stops on a particle faster than
    sound. Now: exit 3 within a few steps, one line naming the law's key and a particle, the state written."""
    res = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path, *LAW_RUN, "--quiet",
                   "--set", f"shifting.method={law}", "--set", f"shifting.{key.split('.')[1].split(' ')[0]}=1e6")
    assert res.returncode == 3, res.stderr
    lines = [line for line in res.stderr.splitlines() if line.startswith("psph: error")]
    assert len(lines) == 1 and "the explicit shifting law's velocity reached" in lines[0], res.stderr
    assert "times the speed of sound c0 = 10" in lines[0] and f"the law is too strong ({key}) [step " in lines[0]
    step = int(lines[0].split(" [step ")[1].split(",")[0])  # (from the lattice: step 2 or 3)
    assert step <= 3 and "particle gid " in lines[0] and (tmp_path / "snapshot_000001.h5").exists()


def test_a_kinematic_neuhauser_run_continues_bit_for_bit(tmp_path):
    """Neuhauser's law reads the transport velocity of the step before (a field the checkpoint keeps): a run
    continued from its checkpoint ends with the particles of the run made in one go."""
    args = [*LAW_RUN, "--set", "time.t_end=0.05", "--set", "shifting.method=neuhauser", "--checkpoint-every", "30"]
    done = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path / "whole", *args)
    assert done.returncode == 0, done.stderr
    done = run_psph("run", "--restart", tmp_path / "whole" / "checkpoint_000030.h5", "--out", tmp_path / "again")
    assert done.returncode == 0, done.stderr
    last = "snapshot_000001.h5"
    with h5py.File(tmp_path / "whole" / last) as a, h5py.File(tmp_path / "again" / last) as b:
        assert b.attrs["step"] == 50
        order_a, order_b = np.argsort(a["particles/gid"][()]), np.argsort(b["particles/gid"][()])
        assert np.array_equal(a["particles/position"][()][order_a], b["particles/position"][()][order_b])


def test_failure_stops_with_step_and_saves_state(tmp_path):
    out = tmp_path / "out"
    res = run_psph("run", CASES / "kinematic_tgv.toml", "--out", out, *KINEMATIC, "--set", "iips.beta=1.0001",
                   "--set", "iips.max_newton=1", "--set", "iips.on_stall=stop")
    assert res.returncode == 3
    assert "psph: error: IIPS Newton stalled" in res.stderr and "Traceback" not in res.stderr
    # the place: the particle of largest |grad C| (the saved state is the stalled iterate)
    place = re.search(r"\[step \d+, t = \S+, particle gid (\d+), at \(([^,]+), ([^)]+)\)\]$", res.stderr.strip())
    assert place, res.stderr
    snaps = sorted(out.glob("snapshot_*.h5"))
    with h5py.File(snaps[-1]) as f:
        assert "grad_c" in f["particles"] and f.attrs["step"] >= 1
        gid, pos, grad = (f[f"particles/{name}"][()] for name in ("gid", "position", "grad_c"))
    worst = int(np.argmax(np.linalg.norm(grad, axis=1)))
    assert int(place[1]) == gid[worst]
    assert np.allclose([float(place[2]), float(place[3])], pos[worst], rtol=1e-5, atol=1e-6)


def test_a_static_runs_failure_names_its_iteration_and_place(tmp_path):
    """A static run's failures said neither which iteration nor, for IIPS's own, which particle."""
    static = ["run", CASES / "static_perturbed.toml", "--set", "domain.dx=0.05", "--set", "shifting.method=iips"]
    bare = run_psph(*static, "--out", tmp_path / "a", "--set", "domain.periodic=[false,false]")
    assert bare.returncode == 2 and "the bounded face(s) x-, x+, y-, y+ have no neighbour" in bare.stderr
    stalled = run_psph(*static, "--out", tmp_path / "b", "--set", "iips.threshold=1e-12", "--set",
                       "iips.max_newton=2", "--set", "iips.on_stall=stop")
    assert stalled.returncode == 3, stalled.stderr
    assert re.search(r"after 2 iterations \[iteration 2, particle gid \d+, at \(", stalled.stderr), stalled.stderr


def test_a_static_runs_summary_describes_the_state_it_kept(tmp_path):
    """A stalled static call that undoes its displacements (iips.on_stall = "reject") kept the start, while
    summary.json gave the last iterate's Linf(grad C): the final values now are the kept state's."""
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path, "--quiet", "--set", "domain.dx=0.05",
                   "--set", "shifting.method=iips", "--set", "initial.sigma_over_dx=0.5", "--set",
                   "iips.threshold=1e-12", "--set", "iips.max_newton=3", "--set", "iips.on_stall=reject")
    assert res.returncode == 0, res.stderr
    start = read_history(tmp_path / "history.csv")[0]
    final = json.loads((tmp_path / "summary.json").read_text())["final"]
    assert np.isclose(final["Linf_grad_c"], start["Linf_grad_c"], rtol=1e-9)
    with h5py.File(sorted(tmp_path.glob("snapshot_*.h5"))[-1]) as f:
        grad = f["particles/grad_c"][()]
    assert np.isclose(np.linalg.norm(grad, axis=1).max() * 0.05 * 2.0, start["Linf_grad_c"], rtol=1e-9)
    # the start is the first snapshot's state: no second snapshot of it (two at time 0 ParaView cannot show)
    assert final["iteration"] == 0 and len(list(tmp_path.glob("snapshot_*.h5"))) == 1


def test_a_stalled_static_runs_kept_iterate_is_labelled_with_its_iteration(tmp_path):
    """iips.on_stall = "best" keeps the iterate of lowest Linf(grad C): its snapshot was labelled with the last
    iteration, 12, and summary.json's final values named none (a diagnostics audit: iteration 7's state)."""
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path, "--quiet", "--set", "domain.dx=0.05",
                   "--set", "shifting.method=iips", "--set", "iips.threshold=1e-9", "--set", "iips.max_newton=12")
    assert res.returncode == 0 and "stalled" in (tmp_path / "psph.log").read_text(), res.stderr
    rows = read_history(tmp_path / "history.csv")
    best = min(range(len(rows)), key=lambda k: rows[k]["Linf_grad_c"])
    assert 0 < best < len(rows) - 1 == 12
    final = json.loads((tmp_path / "summary.json").read_text())["final"]
    assert final["iteration"] == best and final["L2_grad_c"] == pytest.approx(rows[best]["L2_grad_c"], rel=1e-9)
    with h5py.File(sorted(tmp_path.glob("snapshot_*.h5"))[-1]) as f:
        assert f.attrs["step"] == best and f.attrs["time"] == best
        grad = f["particles/grad_c"][()]
    assert np.linalg.norm(grad, axis=1).max() * 0.1 == pytest.approx(rows[best]["Linf_grad_c"], rel=1e-9)


def test_a_static_run_level_to_round_off_takes_no_further_newton_step(tmp_path):
    """From a distribution level to round-off a Newton step solves for noise: on 2 and 3 ranks BCGS ended
    DIVERGED_DTOL (1-D, cubic spline, after converging) or BREAKDOWN (2-D, from the lattice), and the run
    stopped as a numerical failure. Now the call ends there, converged."""
    one_d = ["--set", "domain.dimension=1", "--set", "domain.lower=[0.0]", "--set", "domain.upper=[1.0]", "--set",
             "domain.periodic=[true]", "--set", "domain.kernel=cubic_spline", "--set", "shifting.method=iips"]
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path / "a", "--quiet", *one_d, "--set",
                   "domain.dx=0.05", "--set", "initial.sigma_over_dx=0.5", "--set", "iips.max_newton=15")
    assert res.returncode == 0, res.stderr
    rows = read_history(tmp_path / "a" / "history.csv")
    assert len(rows) - 1 < 15 and rows[-1]["Linf_grad_c"] <= 1e-12 < rows[-2]["Linf_grad_c"]
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path / "b", "--quiet", "--set",
                   "domain.dx=0.05", "--set", "initial.sigma_over_dx=0", "--set", "shifting.method=iips")
    assert res.returncode == 0, res.stderr
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["steps"] == 0  # the lattice: nothing to do


@pytest.mark.long
def test_relaxed_start_keeps_procedure_b_from_stalling(tmp_path):
    """The frozen Taylor-Green field strains a lattice into a distribution IIPS cannot level: Procedure B stalls
    from t = 0.055 on (dx = 0.025). The pre-procedure on a perturbed lattice (a relaxed start that is not
    a lattice) lets it keep the threshold at every call, with fewer Newton iterations."""
    summaries = {}
    for sigma in (0.0, 0.25):
        out = tmp_path / f"sigma{sigma}"
        res = run_psph("run", CASES / "kinematic_tgv.toml", "--out", out, "--set", "domain.dx=0.025",
                       "--set", f"initial.sigma_over_dx={sigma}", "--set", "iips.beta=0", "--set",
                       "iips.threshold=0.001", "--set", "iips.pre_newton=40", "--set", "time.t_end=0.1",
                       "--set", "output.every=0", "--set", "output.history_every=100")
        assert res.returncode == 0, res.stderr
        summaries[sigma] = json.loads((out / "summary.json").read_text())
    lattice, relaxed = summaries[0.0], summaries[0.25]
    assert lattice["failed_calls"] > 0 and relaxed["failed_calls"] == 0
    assert relaxed["pre_procedure_linf"] < 1e-3
    assert relaxed["newton_iterations"] < lattice["newton_iterations"]


def one_line(res, code):
    lines = res.stderr.strip().splitlines()
    assert res.returncode == code and len(lines) == 1 and lines[0].startswith("psph: error: "), res.stderr
    return lines[0]


def test_a_threshold_no_call_can_reach_is_refused(tmp_path):
    """A drivers audit: a lattice start leaves the pre-procedure at round-off, and beta x it (2.1e-14) was a
    threshold below round-off, where IIPS takes no step: 9 calls of 10 stalled at 20 iterations, exit 0."""
    lattice = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path / "a", *KINEMATIC,
                       "--set", "initial.sigma_over_dx=0")
    assert "the pre-procedure left a level distribution (a lattice?)" in one_line(lattice, 2)
    small = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path / "s", *KINEMATIC, "--set",
                     "iips.beta=1e-10")  # (from the perturbed start: beta is what is wrong, not the start)
    assert re.search(r"iips\.beta: 1e-10 x Linf\(grad C\) after the pre-procedure \(\S+\) = \S+ is below "
                     r"round-off \(1e-12\), which no call reaches: give a larger iips.beta, or iips.threshold$",
                     one_line(small, 2))
    explicit = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path / "e", *KINEMATIC, "--quiet", "--set",
                        "initial.sigma_over_dx=0", "--set", "shifting.method=explicit_iterative", "--set",
                        "shifting.diffusion=0.01")  # (a review: refused for the beta this run does not read)
    assert explicit.returncode == 0, explicit.stderr
    tiny = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path / "b", *KINEMATIC,
                    "--set", "iips.beta=0", "--set", "iips.threshold=1e-13")
    assert "iips.threshold: 1e-13 is below round-off" in one_line(tiny, 2)
    static = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path / "c", "--set", "iips.beta=5")
    assert "iips.beta: a static run has no pre-procedure to scale: give iips.threshold" in one_line(static, 2)


def test_a_static_run_that_ends_worse_than_it_started_stops_with_its_state(tmp_path):
    """A drivers audit: the cubic spline at h/dx = 2 took L2(grad C) 0.055 -> 0.0094 -> 0.37, ended at 0.135,
    and exited 0 with the worst state called final."""
    out = tmp_path / "out"
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", out, "--set", "shifting.method=iips",
                   "--set", "domain.dx=0.05", "--set", "domain.kernel=cubic_spline")
    line = one_line(res, 3)
    assert "the shifting left the distribution worse than it started: L2(grad C) 0.0548 -> " in line
    # the lowest is the first iterate's (its value, 0.0094 or 0.0107, moves with the KSP's round-off at rtol 1e-2)
    assert re.search(r"\(lowest 0\.0\d+ at iteration 1\)", line) and line.endswith("[iteration 20]"), line
    assert not (out / "summary.json").exists() and len(read_history(out / "history.csv")) == 21
    with h5py.File(out / "snapshot_000001.h5") as last:
        assert last.attrs["step"] == 20


def test_a_failure_in_the_pre_procedure_says_so(tmp_path):
    res = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path, *KINEMATIC, "-iips_ksp_max_it", "4")
    assert "iips linear solve diverged: DIVERGED_MAX_IT after 4 iterations [pre-procedure, iteration 1, particle " \
           "gid " in one_line(res, 3)
    assert (tmp_path / "snapshot_000000.h5").exists()


def test_a_static_runs_escaped_particle_names_its_iteration(tmp_path):
    """The escape check's label in a static run (a shifting that breaks a particle at its second iteration; a
    bounded face without a wall, which pushed particles out, is now refused)."""
    from mpi4py import MPI

    from psph.drivers.static import StaticDriver
    from psph.errors import NumericalError
    from psph.scene.load import load_scene

    scene = load_scene(CASES / "static_perturbed.toml", ["domain.dx=0.1", "shifting.method=iips"])
    driver = StaticDriver(scene, MPI.COMM_SELF, tmp_path)

    def throw(system, on_iteration, iterations=None):
        on_iteration({"newton": 1, "ksp_iterations": 0, "newton_time_s": 0.0})
        system.particles.owned("position")[3] = [np.nan, 0.5]
        system.check_escaped()

    driver.shifting.correct = throw
    with pytest.raises(NumericalError, match=r"1 particle\(s\) with a non-finite position \[iteration 2, particle "
                                             r"gid 3\]"):
        driver.run()


def test_static_iips_keeps_a_drops_free_surface(tmp_path):
    """A drivers audit: static IIPS had no free-surface treatment, and the rim of a drop (here R = 0.25,
    dx = 0.025, 5 iterations) flew out to r = 0.38. Its surface particles now stay, as in a flow's
    pre-procedure (thesis 10.2.1); the explicit iteration, which has no such treatment, is refused."""
    out = tmp_path / "drop"
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", out, "--quiet", "--set", "shifting.method=iips",
                   "--set", "domain.dx=0.025", "--set", "initial.drop_radius=0.25", "--set", "iips.max_newton=5")
    assert res.returncode == 0, res.stderr
    radius = []
    for path in sorted(out.glob("snapshot_*.h5")):
        with h5py.File(path) as f:
            radius.append(np.linalg.norm(f["particles/position"][()] - 0.5, axis=1).max())
    assert len(radius) == 2 and radius[1] == pytest.approx(radius[0], abs=1e-12)  # (0.2528: the perturbation)
    rows = read_history(out / "history.csv")
    assert rows[-1]["L2_grad_c"] < rows[0]["L2_grad_c"]
    explicit = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path / "x", "--set",
                        "shifting.method=explicit_iterative", "--set", "initial.drop_radius=0.25")
    assert "shifting.method: explicit_iterative has no free-surface treatment" in one_line(explicit, 2)


def test_snapshots_show_no_solver_scratch_and_every_snapshot_has_grad_c(tmp_path):
    """A drivers audit: every kinematic snapshot carried IIPS's working fields (its best and first steps), which
    only a checkpoint needs, and only the first and last had grad C. After a restart too."""
    run = ["run", CASES / "kinematic_tgv.toml", "--quiet", *KINEMATIC, "--set", "time.t_end=0.05", "--set",
           "output.every=0.01", "--set", "output.checkpoint_every=20"]
    res = run_psph(*run, "--out", tmp_path / "a")
    assert res.returncode == 0, res.stderr
    checkpoint = sorted((tmp_path / "a").glob("checkpoint_*.h5"))[-1]
    with h5py.File(checkpoint) as f:
        assert {"iips_best_shift", "iips_first_step"} <= set(f["particles"])
        before = json.loads(f["state"][()].tobytes())["wall_time_s"]
    again = run_psph("run", "--restart", checkpoint, "--out", tmp_path / "b", "--quiet")
    assert again.returncode == 0, again.stderr
    # (an I/O audit: a continuation's wall_time_s was its own segment's, its step times the whole run's)
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["wall_time_s"] > before > 0.0
    for out in ("a", "b"):
        snapshots = sorted((tmp_path / out).glob("snapshot_*.h5"))
        assert len(snapshots) >= (5 if out == "a" else 1)  # (the continuation's own, after its checkpoint)
        for path in snapshots:
            with h5py.File(path) as f:
                names = set(f["particles"])
            assert "grad_c" in names and not names & {"iips_best_shift", "iips_first_step", "iips_step", "row"}
    # a flow whose only IIPS is its pre-procedure: the restart's fields learn that they are scratch by name
    flow = ["run", CASES / "taylor_green.toml", "--quiet", "--set", "domain.dx=0.1", "--set",
            "shifting.method=delta_plus", "--set", "iips.update=none", "--set", "initial.sigma_over_dx=0.25", "--set",
            "iips.pre_newton=5", "--set", "time.t_end=0.1", "--set", "output.every=0.02", "--checkpoint-every", "10"]
    assert run_psph(*flow, "--out", tmp_path / "c").returncode == 0
    checkpoint = sorted((tmp_path / "c").glob("checkpoint_*.h5"))[-1]
    assert run_psph("run", "--restart", checkpoint, "--out", tmp_path / "d", "--quiet").returncode == 0
    for path in sorted((tmp_path / "c").glob("snapshot_*.h5")) + sorted((tmp_path / "d").glob("snapshot_*.h5")):
        with h5py.File(path) as f:
            assert not set(f["particles"]) & {"iips_best_shift", "iips_first_step", "iips_step"}, path
