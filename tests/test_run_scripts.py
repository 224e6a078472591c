"""Smoke runs of the study and benchmark scripts of run_scripts/: each runs once, end to end, as a user runs it
(`python run_scripts/NAME.py ...` in a subprocess, from the checkout's root) at the smallest settings that still
take its whole path (the coarsest resolution, the shortest t_end, the fewest cases and methods), on one rank
(tgv_tradeoff.py on two), and must exit 0 and write its tables (finite numbers where the script measures one)
and figures; a benchmark must print its figures (never compared with a time). Scripts rot when psph changes:
these catch a script that no longer runs, not a result that moved.

tests/test_studies.py runs dam_break_long.py and volume_budget.py end to end: they are not run again here. Its
tests of tgv_tradeoff.py (a refused key) and cavity.py (its runs replaced) make no run: both run here. The cases
are in order of their cost, the longest first, so that the two pytest-xdist workers share them
(--maxschedchunk 1).
"""

import csv
import json
import math
import re
import subprocess
import sys

import pytest

from tests.helpers import ROOT, mpi_environment

FIGURE_BYTES = 10_000  # a saved figure with axes and curves (an empty canvas is smaller)


def run_script(name, *args, timeout=300):
    """`python run_scripts/NAME.py ARGS` from the checkout's root; returns its stdout (the exit code must be 0)."""
    env = mpi_environment()
    env.pop("PSPH_STUDY_REUSE", None)  # every run is made (run_scene would read back a finished one)
    cmd = [sys.executable, f"run_scripts/{name}.py", *map(str, args)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT, env=env,
                         stdin=subprocess.DEVNULL)
    assert res.returncode == 0, f"{' '.join(cmd)}: exit {res.returncode}\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}"
    return res.stdout


def number(cell) -> float:
    """A table cell as a number: as the CSV holds it, or as a script formatted it ("12.0%", "1.000")."""
    return float(cell.strip().removesuffix("%"))


def table(path, rows=None):
    """(header, rows) of a table psph.studies.write_table wrote: path.csv, with path.md beside it holding as many
    rows (and `rows` of them, if given)."""
    with open(path.with_suffix(".csv"), newline="") as f:
        header, *data = list(csv.reader(f))
    lines = [line for line in path.with_suffix(".md").read_text().splitlines() if line.startswith("| ")]
    assert len(lines) == len(data) + 1, f"{path}.md: {len(lines) - 1} rows, the CSV {len(data)}"
    assert all(len(row) == len(header) for row in data), path
    if rows is not None:
        assert len(data) == rows, f"{path}: {len(data)} rows, not {rows}"
    return header, data


def finite(header, rows, skip=(), only=None):
    """Every cell of the columns `only` (by name; default: all but `skip`, names or indices) is a finite number."""
    columns = [k for k, name in enumerate(header)
               if (name in only if only is not None else name not in skip and k not in skip)]
    assert columns
    for row in rows:
        for k in columns:
            value = number(row[k]) if row[k] not in ("", "-") else math.nan
            assert math.isfinite(value), f"{header[k]!r} = {row[k]!r} in {row}"


def figures(out, *names):
    """The figures OUT/NAME were saved (with something drawn in them)."""
    for name in names:
        assert (out / name).stat().st_size > FIGURE_BYTES, out / name


def histories(path, labels):
    """The CSV of time histories (psph.studies.write_histories): finite numbers past its `labels` columns, but
    at t = 0 the forces on bodies, which no right-hand side has measured yet (NaN)."""
    with open(path, newline="") as f:
        header, *rows = list(csv.reader(f))
    assert rows and header[labels] == "time"
    start = [row for row in rows if float(row[labels]) == 0.0]
    forces = [k for k, name in enumerate(header) if name.startswith(("cd_", "cl_", "cm_", "force_"))]
    assert all(row[k] == "nan" for row in start for k in forces)
    finite(header, [row for row in rows if row not in start], skip=range(labels))
    finite(header, start, skip=[*range(labels), *forces])


def printed(pattern, stdout):
    """The numbers of the printed line that matches `pattern` (its groups), each finite."""
    found = re.search(pattern, stdout, re.MULTILINE)
    assert found, f"no line {pattern!r} in:\n{stdout}"
    values = [float(v) for v in found.groups()]
    assert all(math.isfinite(v) for v in values), found[0]
    return values


NUM = r"(-?[\d.]+(?:e[-+]?\d+)?)"  # a printed number


# ------------------------------------------------------------------------------------------------- studies

def dam_break(out):
    run_script("dam_break", "--ranks", 1, "--early-resolutions", 5, "--early-sound-speeds", 20, "--resolutions", 5,
               "--t-end", 3, "--impact-resolutions", "--out", out)
    header, rows = table(out / "initial_pressure", rows=2)
    finite(header, rows[:1], only=["RMS error", "max error"])  # "start": the hydrostatic pressure it starts from
    finite(header, rows[1:])
    # the run to t_end = 3 makes both tables: the impact's, whose last column is the wall time of its own runs to
    # t = 3 (none: "-"), and the runs' to t_end, whose P1 after t = 5 it does not reach; at H/dx = 5 the front
    # reaches the right wall at t = 2.98, just in time (nan if it does not: a result, not a broken script)
    header, rows = table(out / "impact", rows=1)
    assert header[-1] == "wall s (runs to t = 3)" and rows[0][-1] == "-"
    finite(header, rows, skip=[len(header) - 1, "front at the wall, t"])
    finite(*table(out / "dam_break", rows=1), skip=["P1 max t >= 5, average", "raw"])
    histories(out / "histories.csv", 1)
    figures(out, "front.png", "p1.png", "impact.png", "energy.png", "snapshots.png")


def iips_vs_explicit(out):
    run_script("iips_vs_explicit", "--dx", 0.05, "--wavelengths", 0.5, "--settings", "assembled_tuned", "--repeats",
               1, "--ranks", 1, "--out", out)
    header, rows = table(out / "table_8_2", rows=1)
    assert rows[0][:3] == ["1", "10", "assembled_tuned"]  # ranks, particles per wavelength, IIPS settings
    finite(header, rows, skip=[2, 6, 7, 8])
    its, time, speed_up = rows[0][6:9]  # D = 0.5 h^2, Lind's: it diverges (the docstring), as the cell says
    assert (its and time == speed_up == "-") or all(math.isfinite(number(v)) for v in (its, time, speed_up))


def iips_kinematic(out):
    run_script("iips_kinematic", "--resolutions", 0.1, "--ratios", 2.0, "--t-end", 0.02, "--out", out)
    finite(*table(out / "cost", rows=4), skip=["procedure"])  # the procedures A, B (beta 5, 10), C
    finite(*table(out / "errors", rows=4), skip=["procedure"])
    assert table(out / "table_8_3", rows=1) == (["h/dx"], [["2.0"]])  # one resolution: no convergence rate
    figures(out, "histories.png")


def neuhauser_kinematic(out):
    run_script("neuhauser_kinematic", "--dx", 0.1, "--t-end", 0.01, "--out", out)
    header, rows = table(out / "table", rows=8)  # no shifting, P_S = 1 .. 20, c0 = 20 and 100
    finite(header, rows, skip=["run", "thesis fig."])
    assert [r[6] for r in rows] == ["5", "5", "5", "5", "5", "5", "10", "50"]  # steps: dt = 0.2 dx / c0
    figures(out, "histories.png")


def elliptical_drop(out):
    # to t A0 = 0.25 (the runs of the packing sweep too, whose packing is the same)
    run_script("elliptical_drop", "--resolutions", 10, "--alphas", 0.01, "--alpha-resolution", 10, "--set",
               "time.t_end=0.25", "--out", out)
    header, rows = table(out / "drop", rows=2)
    assert [row[1] for row in rows] == ["lattice", "packed"]
    unpacked = ["packing s", "Linf(grad Gamma) h lattice", "packed"]  # the lattice run packs nothing
    finite(header, rows[:1], skip=["start", *unpacked])
    finite(header, rows[1:], skip=["start"])
    finite(*table(out / "packing", rows=1))
    figures(out, "axes.png", "particles.png", "packing.png")


def free_surface(out):
    run_script("free_surface", "--drop-resolutions", 10, "--tank-resolutions", 5, "--methods", "delta_plus",
               "--ranks", 1, "--set", "time.t_end=0.2", "--out", out)
    finite(*table(out / "drop", rows=1), skip=["shifting"])
    finite(*table(out / "tank", rows=1), skip=["shifting"])
    figures(out, "drop_axes.png", "surface.png", "tank_speed.png")


def ellipse(out):
    run_script("ellipse", "--resolutions", 5, "--t-end", 0.1, "--out", out)
    header, rows = table(out / "forces", rows=1)
    # no lift frequency in a run this short (studies.dominant_frequency: nan); the range is "low-high"
    finite(header, rows, skip=["St = f a / U (lift)", "cd_viscous range"])
    assert all(math.isfinite(float(v)) for v in rows[0][header.index("cd_viscous range")].split("-", 1))
    histories(out / "histories.csv", 1)
    figures(out, "drag.png", "volume_error.png", "variations_a5.png")


def triangle(out):
    run_script("triangle", "--resolutions", 10, "--t-end", 0.1, "--corners", "upstream", "--out", out)
    header, rows = table(out / "forces", rows=5)  # the run, then the seed's four
    assert rows[0][0] == "corner upstream, N = 10" and rows[1][0].startswith("seed 004")
    # no shedding yet: a lift of round-off, and no Strouhal number
    finite(header, rows[:1], skip=["run", "St", "window t U / D", "stop"])
    assert rows[0][-1] == "-"
    assert abs(float(rows[0][header.index("C_L amplitude")])) < 1e-6 and rows[0][header.index("St")] == "nan"
    figures(out, "cd.png", "cl.png", "cm.png")
    # a run by hand with the study's settings (the other orientation) is tabled with --in-progress only
    vertices = ("bodies.2.vertices=[[0.5773502691896258, 0.0], [-0.2886751345948129, 0.5], [-0.2886751345948129, "
                "-0.5]]")  # (the study's "downstream")
    res = subprocess.run([sys.executable, "-m", "psph", "run", "cases/triangular_cylinder.toml", "--out",
                          str(out / "downstream_n10"), "--set", "domain.dx=0.1", "--set", "time.t_end=0.1", "--set",
                          vertices], capture_output=True, text=True, cwd=ROOT, env=mpi_environment(), timeout=300)
    assert res.returncode == 0, res.stderr
    res = subprocess.run([sys.executable, "run_scripts/triangle.py", "--resolutions", "10", "--t-end", "0.1",
                          "--out", str(out), "--overwrite"], capture_output=True, text=True, cwd=ROOT,
                         env=mpi_environment(), timeout=300)
    assert res.returncode == 1 and "not a finished run of this study's command" in res.stderr
    run_script("triangle", "--resolutions", 10, "--t-end", 0.1, "--out", out, "--in-progress", "--overwrite")
    header, rows = table(out / "forces", rows=6)
    assert [row[0] for row in rows[:2]] == ["corner upstream, N = 10", "corner downstream, N = 10"]
    drag = [float(row[header.index("C_D mean")]) for row in rows[:2]]
    assert drag[0] != drag[1] and all(math.isfinite(c) for c in drag)


def tank(out):
    run_script("tank", "--resolutions", 8, "--trapezoid-resolutions", 5, "--t-end", 0.2, "--schemes", "delta_ale",
               "riemann_ale", "--out", out)
    header, rows = table(out / "spurious", rows=6)
    assert [row[:3] for row in rows] == [[tank, walls, scheme] for tank, walls in
                                         [("box", "clone"), ("box", "ghost"), ("trapezoid", "clone")]
                                         for scheme in ("delta_ale", "riemann_ale")]
    weight = next(name for name in header if name.startswith("weight on the tank"))
    finite(header, rows, skip=["tank", "walls", "scheme", weight])
    finite(header, [row for row in rows if row[1] == "clone"], only=[weight])  # ghost walls report no force (nan)
    rms, deep, worst = (header.index(name) for name in ("RMS p error", "max p error, y < 0.3 H", "max p error"))
    assert all(float(row[deep]) <= float(row[worst]) for row in rows)
    assert all(rows[k][rms] != rows[k + 1][rms] for k in range(0, 6, 2))  # the Riemann scheme ran
    figures(out, "speed.png")


def riemann_walls(out):
    run_script("riemann_walls", "--schemes", "riemann_ale", "--shiftings", "none", "--cavity-dx", 0.1,
               "--cavity-t-end", 0.05, "--dam-dx", 0.1, "--dam-t-end", 0.05, "--square-dx", 0.2, "--square-t-end",
               0.05, "--out", out)
    header, rows = table(out / "runs", rows=3)
    assert [row[0] for row in rows] == ["cavity", "dam_break", "moving_square"]
    assert all(row[1:3] == ["riemann_ale", "none"] for row in rows)
    fronts = [name for name in header if name.startswith("front")]  # (the dam break's, after t = 1)
    finite(header, rows, skip=["flow", "scheme", "shifting", "stop", *fronts])
    assert float(rows[0][header.index("t reached")]) == 0.05 and rows[0][-1] == "-"


def couette(out):
    run_script("couette", "--schemes", "delta_ale", "riemann_low", "--viscosities", "morris", "--resolutions", 10,
               20, "--t-end", 0.05, "--out", out)
    header, rows = table(out / "runs", rows=4)
    assert [row[:3] for row in rows] == [["delta_ale", "morris", "10"], ["delta_ale", "morris", "20"],
                                         ["riemann_low", "morris", "10"], ["riemann_low", "morris", "20"]]
    order = "order against the previous H/dx"
    finite(header, rows, skip=["scheme", "viscosity", order, "stop"])
    error = [float(row[header.index("max abs(u_x - u_exact)")]) for row in rows]
    # t = 0.05: the plate's shear is steep yet (0.12 at H/dx = 10, 0.03 at 20); the schemes differ
    assert max(error) < 0.2 and error[1] < 0.5 * error[0] and error[3] < 0.5 * error[2] and error[0] != error[2]
    for coarse, fine in ((0, 1), (2, 3)):  # the order between the two resolutions, 2 apart
        assert float(rows[fine][header.index(order)]) == pytest.approx(math.log2(error[coarse] / error[fine]), rel=0.01)
    assert all(row[-1] == "-" for row in rows)


def iips_static(out):
    run_script("iips_static", "--resolutions", 0.1, "--ratios", 2.0, "--out", out)
    header, rows = table(out / "histories", rows=2)  # the two sigmas
    finite(header, rows, skip=["it to 1e-3 drop", "it to 5% of Cartesian L2(df/dx)"])  # an iteration, or "never"
    header, rows = table(out / "table_8_1", rows=1)
    finite(header, rows, skip=["rate"])  # one resolution: no rate
    figures(out, "histories.png")


def iips_tradeoff(out):
    run_script("iips_tradeoff", "--quick", "--out", out)
    header, rows = table(out / "static", rows=3)
    assert [row[:3] for row in rows] == [["2.0", "jacobi", "0.01"], ["2.0", "jacobi_assembled", "0.1"],
                                         ["1.6", "jacobi", "0.01"]]
    finite(header, rows, skip=["PC", "monotonic (it 0-5)", "Pareto"])
    assert "*" in [row[-1] for row in rows]  # the Pareto front
    finite(*table(out / "kinematic", rows=2), skip=["PC"])
    figures(out, "tradeoff.png")


def moving_square(out):
    run_script("moving_square", "--dx", 0.2, "--t-end", 0.05, "--methods", "explicit P_S=10", "IIPS + NFTS",
               "--out", out)
    header, rows = table(out / "cost", rows=2)
    finite(header, rows, skip=["method", "mean cd (t>=2)"])  # the runs end before t = 2
    assert float(rows[0][header.index("wall / explicit")]) == 1.0
    histories(out / "histories.csv", 2)
    figures(out, "drag.png", "grad_c.png")


def tgv_tradeoff(out):
    """The one study on two ranks."""
    run_script("tgv_tradeoff", "--ranks", 2, "--resolutions", 0.1, "--methods", "IIPS", "--t-end", 0.05, "--out", out)
    header, rows = table(out / "convergence", rows=1)
    assert header == ["method", "L2 dx=0.1", "rate", "E_k error dx=0.1"]
    finite(header, rows, skip=["method", "rate"])  # one resolution: no rate
    header, rows = table(out / "tradeoff", rows=1)
    finite(header, rows, skip=["method", "Pareto"])  # (the IIPS time over the rest of the step too)
    assert rows[0][-1] == "*"  # a front of one
    figures(out, "tradeoff.png")
    assert json.loads((out / "IIPS_dx0.1" / "summary.json").read_text())["ranks"] == 2


def tgv_operator_error(out):
    """On the runs tgv_tradeoff.py writes (one of them, to t = 1), and on a square lattice."""
    run_script("tgv_tradeoff", "--resolutions", 0.1, "--methods", "no shifting", "--out", out / "tgv")
    run_script("tgv_operator_error", "--runs", out / "tgv", "--lattices", 10, "--h-over-dx", 2, "--out", out / "ops")
    header, rows = table(out / "ops" / "operators", rows=2)
    assert [row[0] for row in rows] == ["square lattice 10 x 10", "tgv/noshifting_dx0.1"]
    finite(header, rows[:1], skip=["distribution", "run: L2|v_x - v_xA|", "run: E_k error"])  # a lattice: no run
    finite(header, rows[1:], skip=["distribution"])


def cavity(out):
    # history rows every 5 steps (not 50): a row with the lid's flow before the last fifth ("KE change")
    run_script("cavity", "--resolutions", 10, "--t-end", 0.1, "--history-every", 5, "--out", out)
    finite(*table(out / "deviation", rows=1), skip=["walls", "shifting"])
    histories(out / "histories.csv", 3)
    figures(out, "centrelines_Re100.png", "volume_error.png")


def stability_map(out):
    run_script("stability_map", "--dx", 0.1, "--t-end", 0.02, "--sigmas", 0, "--ratios", 2, "--c0", 5,
               "--reynolds", 10, "--methods", "none", "--out", out)
    header, rows = table(out / "map", rows=1)
    assert rows[0][5] == "ran", rows
    for row in rows:
        assert math.isfinite(float(row[6].removeprefix("L2|v_x - v_xA| = "))), row
    figures(out, "map.png")


def impinging_jet(out):
    run_script("impinging_jet", "--resolutions", 8, "--methods", "delta_plus", "--iips-resolutions", "--t-end", 0.3,
               "--average-from", 0.15, "--ranks", 1, "--out", out)
    finite(*table(out / "jet", rows=1), skip=["shifting"])
    figures(out, "wall_pressure.png", "stagnation.png")


def iips_pair_defects(out):
    stdout = run_script("iips_pair_defects", "--dx", 0.0625, "--h-over-dx", 3, "--t-end", 0.02, "--every", 0.01,
                        "--ranks", 1, "--out", out)
    assert "reached t_end" in stdout
    header, rows = table(out / "defects", rows=2)
    assert rows[0][0] == "square lattice 16 x 16" and rows[1][0].startswith("Taylor-Green run, t = 0.02")
    corr = "corr(ratio, nearest distance)"
    finite(header, rows[1:], skip=["distribution"] + header[-2:])
    assert rows[0][header.index(corr)] == "-"  # every particle of the lattice as near
    for row in rows:  # " / "-separated iterations
        for cell in row[-2:]:
            assert all(math.isfinite(number(v)) for v in cell.split(" / ")), row


def viscous_limit_check(out):
    run_script("viscous_limit_check", "--ratios", 2.0, "--kernels", "wendland_c6", "--out", out)
    header, rows = table(out / "estimate", rows=2)  # the two operators
    finite(header, rows, skip=["kernel", "operator"])


# ------------------------------------------------------------------------------------------------- benchmarks

def bench_memory(out):
    stdout = run_script("bench_memory", "--cases", "tgv", "--dx", 0.1, 0.05)
    printed(rf"^\s+tgv\s+1\s+100\s+{NUM}\s+{NUM}\s+{NUM}$", stdout)
    printed(rf"^\s+tgv\s+1\s+400\s+{NUM}\s+{NUM}\s+{NUM}\s+{NUM} / {NUM}$", stdout)
    assert re.search(r"^target: estimate / peak within 1.0-1.5: (met|missed by .+)$", stdout, re.MULTILINE), stdout


def bench_walls(out):
    stdout = run_script("bench_walls", "--steps", 2, "--cases", "lid_driven_cavity", "--set", "domain.dx=0.05",
                        "--out", out)
    printed(rf"^lid_driven_cavity: \d+ particles, 1 rank\(s\), [23] steps: walls {NUM} s of the step's {NUM} s = "
            rf"{NUM}% \(max over ranks\), {NUM} ms per step$", stdout)
    finite(*table(out / "walls_1ranks", rows=1), skip=["scene", "shifting"])


def bench_iips(out):
    stdout = run_script("bench_iips", "--sizes", 20, "--iterations", 1)
    printed(rf"STREAM triad bandwidth {NUM} GB/s", stdout)
    printed(r"^400 particles \(800 local rows, (\d+) local nonzeros on rank 0, \w+\)$", stdout)
    printed(rf"^  time per one-iteration call {NUM} ms", stdout)
    printed(rf"^  KSP iterations per Newton iteration {NUM}", stdout)
    printed(rf"^  time per KSP iteration {NUM} ms, bandwidth bound {NUM} ms -> {NUM} x the bound$", stdout)


def bench_sums(out):
    stdout = run_script("bench_sums", "--sizes", 10, "--min-time", 0.01)
    neighbours = printed(r"^\s+100" + rf"\s+{NUM}" * 7 + r"\s*$", stdout)[0]
    assert 40 < neighbours < 50  # C6 at h = 2 dx: ~45 in the support


def bench_flow(out):
    stdout = run_script("bench_flow", "--sizes", 10, "--shifting", "none", "--seconds", 0.1)
    printed(rf"^\s+100\s+none\s+0.1\s+{NUM}\s+{NUM}\s", stdout)


SCRIPTS = [iips_vs_explicit, elliptical_drop, dam_break, iips_tradeoff, iips_kinematic, free_surface, tank, ellipse,
           moving_square, iips_static, tgv_operator_error, cavity, tgv_tradeoff, impinging_jet, iips_pair_defects,
           stability_map, bench_memory, bench_iips, viscous_limit_check, bench_walls, bench_sums, bench_flow,
           neuhauser_kinematic, riemann_walls, couette, triangle]


@pytest.mark.parametrize("script,args,message", [
    ("bench_flow", ["--shifting", "iips"], "argument --shifting: invalid choice: 'iips' (choose from 'none', "
                                           "'lind', 'skillen', 'oger', 'delta_plus', 'neuhauser')"),  # an "iips" row
    ("bench_flow", ["--seconds", "-1"], "argument --seconds: must be a finite number > 0, got -1"),  # ran on
    ("bench_sums", ["--min-time", "-1"], "argument --min-time: must be a finite number > 0, got -1"),
    ("bench_memory", ["--ranks", "0"], "argument --ranks: must be >= 1, got 0"),  # ZeroDivisionError
    ("bench_memory", ["--dx", "0.1", "0.1"], "--dx: two different grid spacings, got 0.1 twice"),
    ("bench_walls", ["--steps", "0"], "argument --steps: must be >= 1, got 0")])
def test_a_benchmark_refuses_a_bad_argument_in_one_line(script, args, message):
    """A benchmark audit: these ran on silently, printed a mislabelled row or ended in a traceback."""
    res = subprocess.run([sys.executable, f"run_scripts/{script}.py", *args], capture_output=True, text=True,
                         timeout=120, cwd=ROOT, env=mpi_environment())
    assert res.returncode == 2 and res.stderr.strip().splitlines()[-1] == f"{script}.py: error: {message}", res.stderr


MEMORY = r"\d[\d.e+]* particles would need about [\d.e+]+ GiB, more than 80% of this machine's [\d.]+ GiB"


@pytest.mark.parametrize("script,args,message", [
    ("iips_kinematic", ["--resolutions", "0.1", "0.1"], "argument --resolutions: 0.1 given twice"),  # ZeroDivision
    ("iips_static", ["--ranks", "0"], "argument --ranks: must be >= 1, got 0"),  # ran on one rank
    ("iips_static", ["--out", "{tmp}/file"], "argument --out: {tmp}/file is a file, not a directory"),  # traceback
    ("cavity", ["--out", "/proc/x"], "argument --out: cannot create /proc/x: No such file or directory"),
    ("bench_walls", ["--out", "/proc/x"],  # failed after the measurement
     "argument --out: cannot create /proc/x: No such file or directory"),
    ("viscous_limit_check", ["--out", "{tmp}/file/table"],
     "argument --out: {tmp}/file/table lies in {tmp}/file, a file, not a directory"),
    ("cavity", ["--re", "50", "100", "0"], "argument --re: must be >= 1, got 0"),
    ("cavity", ["--re", "50", "100"],  # KeyError after the runs
     "argument --re: no reference data for Re = 50 (Ghia et al. 1982 in ghia1982_Re100_Re1000.csv: Re = 100, 1000)"),
    ("cavity", ["--h-over-dx", "0"],  # ignored: the scene's 2 ran
     "argument --h-over-dx: h/dx must be within 1 and 4 (as psph's domain.h_over_dx), got 0"),
    ("ellipse", ["--resolutions", "0"], "argument --resolutions: must be >= 1, got 0"),  # ZeroDivisionError
    ("triangle", ["--resolutions", "8"],  # refused by the scene at its first run
     "argument --resolutions: D/dx = 8 puts the inflow buffer's face or the plates off the particle lattice (give a "
     "multiple of 10)"),
    ("viscous_limit_check", ["--ratios", "0.5"],  # ZeroDivisionError; 0, nan: psph's ValueError; 1e9: 30 GiB
     "argument --ratios: h/dx must be within 1 and 4 (as psph's domain.h_over_dx), got 0.5"),
    ("viscous_limit_check", ["--ratios", "nan"],
     "argument --ratios: h/dx must be within 1 and 4 (as psph's domain.h_over_dx), got nan"),
    ("viscous_limit_check", ["--ratios", "1e9"],
     "argument --ratios: h/dx must be within 1 and 4 (as psph's domain.h_over_dx), got 1e9"),
    ("tgv_operator_error", ["--runs", "{tmp}", "--lattices", "2", "--h-over-dx", "2"],  # tabled grad p errors of 3e12
     "argument --lattices / --h-over-dx: lattice 2 x 2, h/dx = 2 on 4 particles (dx = 0.5): the kernel support 2 is "
     "not smaller than the periodic unit box; use more particles or a smaller h/dx"),
    ("tgv_operator_error", ["--runs", "{tmp}", "--lattices", "0"], "argument --lattices: must be >= 1, got 0"),
    ("tgv_operator_error", ["--runs", "{tmp}", "--lattices", "100000"], "argument --lattices: 100000: " + MEMORY),
    ("bench_flow", ["--sizes", "100000"], "argument --sizes: 100000: " + MEMORY),  # 74.5 GiB allocation failed
    ("bench_iips", ["--sizes", "100000"], "argument --sizes: 100000: " + MEMORY),
    ("bench_sums", ["--sizes", "100000"], "argument --sizes: 100000: " + MEMORY),
    ("bench_memory", ["--cases", "tgv", "--dx", "0.1", "0.1000000001"],  # ZeroDivisionError after the runs
     "--dx 0.1 0.1000000001: the same 100 particles (case tgv); give two spacings whose lattices differ"),
    ("stability_map", ["--methods", "bogus"],  # a refused first case emptied a finished map
     "argument --methods: invalid choice: 'bogus' (choose from 'none', 'iips', 'explicit_iterative', 'lind', "
     "'skillen', 'oger', 'delta_plus', 'neuhauser')")])
def test_a_study_refuses_a_bad_argument_in_one_line_before_any_run(script, args, message, tmp_path):
    """A study audit: these ended in a traceback (some after all their runs), ran on silently or tabled
    nonsense. Every refusal is one line (no usage), exit code 2, before any computation."""
    (tmp_path / "file").write_text("")
    args = [a.format(tmp=tmp_path) for a in args]
    res = subprocess.run([sys.executable, f"run_scripts/{script}.py", *args], capture_output=True, text=True,
                         timeout=120, cwd=ROOT, env=mpi_environment())
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert re.fullmatch(f"{script}.py: error: " + re.escape(message.format(tmp=tmp_path)).replace(
        re.escape(MEMORY), MEMORY), res.stderr.strip()), res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]  # nothing written


def test_every_script_is_run_here_or_in_test_studies():
    """A script added to run_scripts/ gets its smoke run (here, or end to end in tests/test_studies.py)."""
    elsewhere = {"dam_break_long", "volume_budget"}
    assert {p.stem for p in (ROOT / "run_scripts").glob("*.py")} == {f.__name__ for f in SCRIPTS} | elsewhere
    studies = (ROOT / "tests" / "test_studies.py").read_text()
    assert all(f'study_module("{name}")' in studies for name in elsewhere)


@pytest.mark.parametrize("script", SCRIPTS, ids=[f.__name__ for f in SCRIPTS])
def test_the_script_runs_end_to_end(script, tmp_path):
    script(tmp_path / "out")
