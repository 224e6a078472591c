"""psph plot --line: the last snapshot's fields along a segment (Shepard interpolation with the run's kernel)."""

import numpy as np
import pytest

from psph.analytic import taylor_green
from tests.helpers import CASES, run_psph

T_END = 0.002  # one or two steps: the fields are the analytic ones at t_end to within the scheme's error


def taylor_green_run(out, dx, *sets):
    res = run_psph("run", CASES / "taylor_green.toml", "--out", out, "--quiet", "--set", f"domain.dx={dx}",
                   "--set", f"time.t_end={T_END}", "--set", "shifting.method=none", "--set", "iips.update=none",
                   *sets)
    assert res.returncode == 0, res.stderr
    return out


def cut(out, *args):
    res = run_psph("plot", out, "--line", *args)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == f"psph: wrote {out / 'figures' / 'line.png'}", res.stdout
    with open(out / "figures" / "line.csv") as f:
        header = f.readline().strip().split(",")
    return header, np.loadtxt(out / "figures" / "line.csv", delimiter=",", skiprows=1, ndmin=2)


def test_a_line_cut_of_taylor_green_converges_to_the_analytic_field_at_second_order(tmp_path):
    """The cut's velocity and pressure against the analytic vortex along y = 0.25, ends on the periodic faces
    (whose images must count: without them a Shepard average at x = 0 takes one side's values only). The
    interpolation smooths by O(h^2): halving dx divides the error by about 4."""
    errors = []
    for dx in (0.05, 0.025):
        header, data = cut(taylor_green_run(tmp_path / f"dx{dx}", dx), "0", "0.25", "1", "0.25", "--points", "41")
        assert header == ["s", "x", "y", "p", "rho", "u", "v"] and data.shape == (41, 7)
        assert np.allclose(data[:, 0], np.linspace(0.0, 1.0, 41)) and np.allclose(data[:, 2], 0.25)
        vel, p = taylor_green(data[:, 1:3], T_END, reynolds=100.0)
        errors.append((np.abs(data[:, 5:7] - vel).max(), np.abs(data[:, 3] - p).max()))
        assert abs(data[0, 5] - data[-1, 5]) < 1e-9  # x = 0 and x = 1 are the same point of the periodic box
    (u1, p1), (u2, p2) = errors
    assert u2 < 0.02 and 3.0 < u1 / u2 < 5.0, errors
    assert 3.0 < p1 / p2 < 5.0, errors


def test_a_line_cut_in_3d_and_through_the_air(tmp_path):
    """A 3-D run is cut along z (fields.png has no 3-D figure); points with no fluid within a kernel support
    read nan, and a segment where no fluid reaches at all is refused."""
    out = tmp_path / "slab"
    res = run_psph("run", CASES / "taylor_green.toml", "--out", out, "--quiet", "--set", "domain.dimension=3",
                   "--set", "domain.lower=[0,0,0]", "--set", "domain.upper=[0.6,0.6,1.2]", "--set",
                   "domain.periodic=[true,true,false]", "--set", "domain.dx=0.1", "--set", "initial.velocity=zero",
                   "--set", "initial.fill_upper=[0.6,0.6,0.4]", "--set", "time.t_end=1e-4")
    assert res.returncode == 0, res.stderr
    header, data = cut(out, "0.3", "0.3", "0", "0.3", "0.3", "1.2", "--points", "13")
    assert header == ["s", "x", "y", "z", "p", "rho", "u", "v", "w"]
    wet = np.isfinite(data[:, 4])
    assert wet[:8].all() and not wet[8:].any(), data[:, [3, 4]]  # rows up to z = 0.35, a support of 0.4
    assert np.allclose(data[wet, 5], 1.0, atol=1e-3)
    dry = run_psph("plot", out, "--line", "0.3", "0.3", "0.9", "0.3", "0.3", "1.2")
    assert dry.returncode == 2 and "no fluid particle lies within a kernel support" in dry.stderr, dry.stderr


@pytest.mark.parametrize("args, words", [
    (["0", "0.5", "1"], "--line: a 2-D run's segment takes 4 numbers (its two ends' coordinates), got 3"),
    (["-0.5", "0.5", "1", "0.5"], "--line: the end [-0.5, 0.5] lies outside the domain along axis 0 (0 .. 1)"),
    (["0", "0.5", "1", "x"], "argument --line: invalid float value: 'x'"),
    # (argparse took a number in exponent form for an option: "unrecognized arguments")
    (["-1e-3", "0.5", "1", "0.5"], "--line: the end [-0.001, 0.5] lies outside the domain along axis 0 (0 .. 1)"),
    # (a review: nan passed and was told "no fluid"; a point or a single point drew nothing)
    (["0", "nan", "1", "0.5"], "--line: the ends' coordinates must be finite numbers, got [0.0, nan, 1.0, 0.5]"),
    (["0.5", "0.5", "0.5", "0.5"], "--line: the two ends coincide"),
    (["0", "0.5", "1", "0.5", "--points", "1"], "argument --points: a line takes 2 to 100000 points, got 1"),
    (["0", "0.5", "1", "0.5", "--points", "0"], "argument --points: a line takes 2 to 100000 points, got 0"),
    (["0", "0.5", "1", "0.5", "--figures", ""], "argument --figures: expected a directory, got an empty string"),
    (["0", "0.5", "1", "0.5", "--points", "100000000"],
     "argument --points: a line takes 2 to 100000 points, got 100000000"),
])
def test_a_bad_line_is_one_line_naming_it(tmp_path, args, words):
    out = taylor_green_run(tmp_path / "tg", 0.1)
    res = run_psph("plot", out, "--line", *args)
    assert res.returncode == 2 and res.stderr.strip() == f"psph: error: {words}", res.stderr
    assert not (out / "figures" / "line.csv").exists()


def test_a_static_run_has_no_flow_to_cut(tmp_path):
    out = tmp_path / "static"
    res = run_psph("run", CASES / "static_perturbed.toml", "--out", out, "--quiet", "--set", "domain.dx=0.1",
                   "--set", "iips.max_newton=1")
    assert res.returncode == 0, res.stderr
    res = run_psph("plot", out, "--line", "0", "0.5", "1", "0.5")
    assert res.returncode == 2 and "holds none of pressure, density, velocity" in res.stderr, res.stderr


@pytest.mark.parametrize("damage, words", [("kind", "is not a psph snapshot: no kind"),
                                           ("position", "is damaged: position holds 5 rows for 100 particles"),
                                           ("pressure", "is damaged: pressure holds |S3 values of shape (100,)")])
def test_a_damaged_last_snapshot_is_one_line_naming_it(tmp_path, damage, words):
    """A review: a snapshot without its kinds, or with positions cut short, ended in a KeyError or a numpy
    broadcast error, "internal error (a bug)", for the cut and for fields.png alike."""
    import h5py

    out = taylor_green_run(tmp_path / "tg", 0.1)
    last = sorted(out.glob("snapshot_*.h5"))[-1]
    with h5py.File(last, "a") as f:
        values = f["particles"][damage][()]
        del f["particles"][damage]
        if damage == "position":
            f["particles/position"] = values[:5]
        if damage == "pressure":  # (a review: a field of strings, "internal error")
            f["particles/pressure"] = np.array([b"abc"] * len(values))
    for args in (["--line", "0", "0.5", "1", "0.5"], []):
        res = run_psph("plot", out, *args)
        assert res.returncode == 2 and res.stderr.strip() == f"psph: error: the last snapshot {last.name} {words}", \
            res.stderr


def test_a_run_in_progress_is_cut_and_plotted_with_the_scene_its_snapshots_carry(tmp_path, monkeypatch):
    """A plot audit: a run with neither summary.json nor a checkpoint (in progress, or killed) had its --line
    refused ("holds no snapshot of a run to cut") and its fields.png without |grad C| h, for want of the
    scene; every snapshot now carries it (attribute "scene")."""
    import psph.plot as plot_module

    out = taylor_green_run(tmp_path / "tg", 0.1)
    done = cut(out, "0", "0.25", "1", "0.25", "--points", "11")[1]
    (out / "summary.json").unlink()
    assert np.array_equal(cut(out, "0", "0.25", "1", "0.25", "--points", "11")[1], done)
    titles = []
    monkeypatch.setattr(plot_module, "_save", lambda plt, fig, path, title=None: titles.append(
        [ax.get_title() for ax in fig.axes]) or path)
    plot_module.plot_fields(out, out / "figures")
    assert "|grad C| h" in titles[0], titles
