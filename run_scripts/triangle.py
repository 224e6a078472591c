"""Flow past a triangular cylinder at Re = 1000 (seed 004 section IV.1): force coefficients and Strouhal
number against the seed's Table I.

    .venv/bin/python run_scripts/triangle.py [--resolutions 10] [--corners upstream downstream]
        [--t-end 60] [--ranks 1] [--in-progress] [--rerun]

For each D/dx (the seed's N) and each orientation it runs cases/triangular_cylinder.toml to t_end and
writes, in --out (results/triangle): forces.md and .csv, over the second half of the time reached and
from a running mean over 0.5 D / U (SMOOTHING; the forces' particle noise): the mean drag C_D, the
oscillation amplitudes (half the range) of C_D, C_L and C_M (pressure + viscous parts,
2 F / (rho0 U^2 D) and 2 M / (rho0 U^2 D^2) about the centroid, D the side: the seed's eq. 10) and the
Strouhal number f D / U of the lift's dominant frequency (studies.dominant_frequency), with the seed's
Table I below them; cd.png, cl.png, cm.png (the coefficients against t U / D). A run psph stopped (a
fluid particle into the triangle, a density out of range) is a row with the time it reached and the stop.

The seed's figure of the section (its Fig. 4) is not in its text, so both orientations are run: `upstream`,
a corner pointing into the stream and the opposite side, normal to it, at the rear (the scene's), and
`downstream`, the triangle turned by 180 degrees. The seed's resolutions are N = 50 to 200 (360 000
particles and more); N = 10 ran to t U/D = 60 in 71 minutes on one core of this machine (partly beside
the test suite).

--in-progress tabulates a run still going, stopped before t_end (SIGTERM writes a checkpoint), or run by
hand with the study's settings (`psph run cases/triangular_cylinder.toml --out OUT/upstream_n10`), from its
history so far; a column gives the time reached. Otherwise a finished run of the study's own command is
read back, never run again, and a directory holding any other run stops the study, unless --rerun.
"""

import argparse
from pathlib import Path

import numpy as np

from psph.io.history import read_history
from psph.studies import (
    CASES,
    RunStopped,
    after,
    command_line,
    dominant_frequency,
    long_run,
    parse_args,
    plot_histories,
    positive_float,
    positive_int,
    stop_message,
    write_table,
)

SCENE = CASES / "triangular_cylinder.toml"
# the scene's triangle (a corner upstream) turned by 180 degrees about its centroid
CORNERS = {"upstream": [], "downstream": ["bodies.2.vertices=[[0.5773502691896258, 0.0], [-0.2886751345948129, 0.5], "
                                          "[-0.2886751345948129, -0.5]]"]}
SMOOTHING = 0.5  # t U / D: the running mean the amplitudes and the Strouhal number are taken from
# seed 004 Table I: C_D mean and amplitude, C_L amplitude, C_M amplitude, St
SEED = [("seed 004: delta+-SPH, N = 50", 3.05, 0.455, 0.721, 0.464, 0.191),
        ("seed 004: delta+-SPH, N = 100", 2.87, 0.475, 0.709, 0.400, 0.199),
        ("seed 004: delta+-SPH, N = 200", 2.73, 0.402, 0.700, 0.349, 0.210),
        ("seed 004: finite volumes (Xnavis)", 2.33, 0.330, 0.650, 0.355, 0.213)]


def total(rows, part, t0):
    """The triangle's coefficient (cd, cl or cm), pressure + viscous parts, over t >= t0 (the plates are
    bodies too: the columns carry the body's name)."""
    return after(rows, f"{part}_pressure_triangle", t0) + after(rows, f"{part}_viscous_triangle", t0)


def half_range(values) -> float:
    return float(0.5 * np.ptp(values)) if values.size else float("nan")


def smoothed(times, values, width=SMOOTHING):
    """(times, values) of values(t) on an even grid of as many samples, as a running mean over `width`
    (t U / D; the times are the means' centres, width less than the span): the forces' particle noise at
    N = 10 (about +-0.5 in C_D from one history row, 10 steps, to the next) would set the half range; the
    shedding's period is about 5."""
    if values.size < 2:
        return times, values
    grid = np.linspace(times[0], times[-1], times.size)
    samples = max(1, int(round(width / (grid[1] - grid[0]))))
    means = np.convolve(np.interp(grid, times, values), np.ones(samples) / samples, mode="valid")
    return grid[:means.size] + 0.5 * (samples - 1) * (grid[1] - grid[0]), means


def resolution(text) -> int:
    """D/dx, refused in one line unless it puts the inflow buffer's face (0.8 D past the domain's edge) and
    the plates' (0.5 D) on the particle lattice."""
    n = positive_int(text)
    if not (0.8 * n).is_integer() or not (0.5 * n).is_integer():
        raise argparse.ArgumentTypeError(f"D/dx = {n} puts the inflow buffer's face or the plates off the particle "
                                         "lattice (give a multiple of 10)")
    return n


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/triangle"))
    parser.add_argument("--resolutions", type=resolution, nargs="+", default=[10], help="D/dx (the seed's N)")
    parser.add_argument("--corners", nargs="+", default=list(CORNERS), choices=list(CORNERS),
                        help="the orientation: a corner pointing upstream, or downstream")
    parser.add_argument("--t-end", type=positive_float, default=60.0, help="t U / D")
    parser.add_argument("--ranks", type=positive_int, default=1)
    parser.add_argument("--in-progress", action="store_true",
                        help="tabulate finished runs and, for the others, what they have written so far")
    parser.add_argument("--rerun", action="store_true", help="run again, over what the run directories hold")
    args = parse_args(parser)
    args.out.mkdir(parents=True, exist_ok=True)
    rows, curves = [], {"cd": [], "cl": [], "cm": []}
    for corner in args.corners:
        for n in args.resolutions:
            sets = [f"domain.dx={1.0 / n}", f"time.t_end={args.t_end}", *CORNERS[corner]]
            out = args.out / f"{corner}_n{n}"
            label = f"corner {corner}, N = {n}"
            try:
                run = long_run(SCENE, out, sets, args.ranks, args.in_progress, args.rerun,
                               compare=(("domain", "dx"), ("time", "t_end"), ("bodies",)))
                stopped = run.summary.get("stopped")  # (a run by hand that psph stopped, --in-progress)
            except RunStopped as err:
                stopped = stop_message(err)
            if stopped:  # diagnosed: its history is written; no window to average over
                history = read_history(out / "history.csv")
                rows.append([label, "-", *[None] * 5, f"stopped at {history[-1]['time']:.3g}",
                             stopped.removeprefix("psph: error: ")])
            else:
                history = run.history
                reached = history[-1]["time"]
                t0 = 0.5 * reached
                times = after(history, "time", t0)
                (_, cd), (grid, cl), (_, cm) = (smoothed(times, total(history, part, t0))
                                                for part in ("cd", "cl", "cm"))
                rows.append([label, run.summary["n_particles"], float(cd.mean()), half_range(cd), half_range(cl),
                             half_range(cm),
                             # a lift of round-off (the symmetric start) sheds nothing
                             dominant_frequency(grid, cl)
                             if half_range(cl) > 1e-6 else np.nan, f"{t0:.3g}-{reached:.3g}", "-"])
            print(rows[-1], flush=True)
            t = after(history, "time", 0.0)
            for part in curves:
                curves[part].append((t, total(history, part, 0.0), f"corner {corner}, N = {n}", {"lw": 0.8}))
    for label, *reference in SEED:
        rows.append([label, "-", *reference, "-", "-"])
    print(write_table(args.out / "forces", ["run", "particles", "C_D mean", "C_D amplitude", "C_L amplitude",
                                            "C_M amplitude", "St", "window t U / D", "stop"], rows, labels=2,
                      title="Triangular cylinder at Re = 1000 (seed 004 section IV.1): force coefficients over the "
                            f"second half of the time reached, running means over {SMOOTHING:g} D / U, amplitudes "
                            "half their range",
                      note="Command: " + command_line()))
    for part, name in (("cd", "C_D"), ("cl", "C_L"), ("cm", "C_M")):
        plot_histories(args.out / f"{part}.png", curves[part], "t U / D", name,
                       f"Triangular cylinder, Re = 1000: {name} (pressure + viscous)", size=(9, 3.5))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
