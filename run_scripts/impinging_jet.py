"""The jet impinging on a flat plate (thesis 000 sections 3.3 and 10.2) against Taylor's wall solution, without
shifting and with the delta+ and Skillen et al. laws (and IIPS, if asked), at H/dx = 10 and 20.

    .venv/bin/python run_scripts/impinging_jet.py [--resolutions 10 20]
                                                  [--methods none delta_plus skillen iips iips_backtrack
                                                             iips_capped]
                                                  [--iips-resolutions 10] [--t-end 10] [--average-from 5]
                                                  [--ranks 2] [--no-run]

cases/impinging_jet.toml: a jet of half-width H = 1 at U = 1 from an inflow buffer 6 H above the plate,
outflow faces 4 H either side, c0 = 10 U. The front's impact at t U/H = 0.5 leaves the stagnation region
ringing (a standing sound wave, period about 0.7 H/U, that the scheme damps slowly), so the figures are time
averages over t U/H in [--average-from, --t-end] of the history's rows and of OUT/wall_pressure.csv:
    p0        stagnation pressure over rho0 U^2 / 2 (1 in Taylor's solution), and its standard deviation
    profile   RMS over |x| <= 2 H of the time-averaged wall pressure minus Taylor's (psph.analytic)
    force     cl = 2 F_y / (rho0 U^2 2 H) on the plate, pressure plus viscous (-2: the jet's momentum flux)
IIPS runs as the thesis runs it with a free surface (section 10.2.2): Procedure A, threshold
Linf(grad C) = 0.02, the MLS II field update, full steps and no bound on what a stalled call keeps (the
scene's iips.stall_max_shift = 0.5 set back to 0); iips_backtrack the same with iips.backtrack = 1 (a Newton step
that raises L2(grad C) is halved, then undone, ending the call); iips_capped the same as iips with
iips.stall_max_shift = 0.5 (a stalled call keeps its best iterate among those that move no particle farther
than 0.5 h = 1 dx). A run that stops is reported in the table with psph's message.
Writes, in --out (results/impinging_jet): jet.md/.csv, wall_pressure.png (time-averaged profiles against
Taylor's) and stagnation.png (p0 against time). --no-run builds them from the finished runs in --out only.
"""

import argparse
import csv
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from psph.analytic import impinging_jet_wall  # noqa: E402
from psph.studies import (  # noqa: E402
    CASES,
    NotRun,
    RunStopped,
    command_line,
    parse_args,
    plot_histories,
    positive_float,
    positive_int,
    run_scene,
    stop_message,
    write_table,
)

IIPS = ["shifting.method=iips", "iips.procedure=A", "iips.threshold=0.02", "iips.update=mls2",
        "iips.stall_max_shift=0"]
METHODS = {"none": ["shifting.method=none"], "delta_plus": ["shifting.method=delta_plus"],
           "skillen": ["shifting.method=skillen"], "iips": IIPS, "iips_backtrack": [*IIPS, "iips.backtrack=1"],
           "iips_capped": [*IIPS, "iips.stall_max_shift=0.5"]}
STYLE = {"none": ":", "delta_plus": "-", "skillen": "-.", "iips": "--", "iips_backtrack": (0, (5, 1, 1, 1)),
         "iips_capped": (0, (1, 1))}
SPAN = 2.0  # |x| / H of the compared stretch (psph.drivers.fluid.ImpingingJetReference.SPAN)


def wall_profile(out, t0):
    """(x, time-averaged wall pressure over rho0 U^2 / 2) from OUT/wall_pressure.csv rows with time >= t0."""
    with open(out / "wall_pressure.csv") as f:
        rows = list(csv.reader(f))
    x = np.array([float(c.split("=")[1]) for c in rows[0][1:]])
    data = np.array([[float(v) for v in r] for r in rows[1:]])
    return x, data[data[:, 0] >= t0, 1:].mean(axis=0)


def summary_row(run, t0):
    h = [r for r in run.history if r["time"] >= t0]
    p0 = np.array([r["stagnation_pressure"] for r in h])
    force = np.array([r["cl_pressure"] + r["cl_viscous"] for r in h])
    x, p = wall_profile(run.out, t0)
    exact = impinging_jet_wall(x)[1] / 0.5
    inside = np.abs(x) <= SPAN + 1e-9
    profile = float(np.sqrt(np.mean((p[inside] - exact[inside]) ** 2)))
    return [p0.mean(), p0.mean() - 1.0, p0.std(), profile, force.mean(), force.mean() / -2.0 - 1.0,
            np.mean([r["min_spacing"] for r in h]), run.summary["wall_time_s"]], (x, p)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/impinging_jet"))
    parser.add_argument("--ranks", type=positive_int, default=2)
    parser.add_argument("--resolutions", type=positive_int, nargs="+", default=[10, 20], help="H/dx")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--iips-resolutions", type=positive_int, nargs="*", default=[10],
                        help="H/dx of the IIPS runs (costly: at H/dx = 10, 601 of 2832 calls stall at 20 "
                        "Newton iterations; docs/results.md, \"Impinging jet\")")
    parser.add_argument("--t-end", type=positive_float, default=10.0)
    parser.add_argument("--average-from", type=float, default=5.0)
    parser.add_argument("--no-run", action="store_true", help="tables and plots from the finished runs only")
    args = parse_args(parser)
    if args.average_from >= args.t_end:
        parser.error(f"--average-from {args.average_from:g} leaves no time to average before --t-end {args.t_end:g}")
    rows, profiles, curves = [], [], []
    for n in args.resolutions:
        for method in args.methods:
            if method.startswith("iips") and n not in args.iips_resolutions:
                continue
            out = args.out / f"jet_{method}_h{n}"
            sets = [f"domain.dx={1.0 / n}", "output.every=0", f"output.history_every={2 * n}",
                    f"time.t_end={args.t_end}", *METHODS[method]]
            try:
                run = run_scene(CASES / "impinging_jet.toml", out, ranks=args.ranks, sets=sets,
                                only_finished=args.no_run)
            except NotRun:
                print(f"{out}: not run", flush=True)
                continue
            except RunStopped as err:  # the run stopped: psph's one-line message
                rows.append([n, method, stop_message(err), *[""] * 7])
                print(rows[-1], flush=True)
                continue
            row, profile = summary_row(run, args.average_from)
            rows.append([n, method, *row])
            print(rows[-1], flush=True)
            profiles.append((f"{method}, H/dx = {n}", STYLE[method], *profile))
            curves.append(([r["time"] for r in run.history], [r["stagnation_pressure"] for r in run.history],
                           f"{method}, H/dx = {n}", {"ls": STYLE[method]}))
    window = f"t U/H in [{args.average_from:g}, {args.t_end:g}]"
    print(write_table(args.out / "jet", [
        "H/dx", "shifting", "p0 / (rho U^2/2)", "p0 error", "p0 std (ringing)",
        f"RMS profile error, x within {SPAN:g} H", "cl (pressure + viscous)", "cl / -2 - 1", "min spacing / dx",
        "wall s"], rows,
        title=f"Impinging jet against Taylor's wall solution: averages over {window}",
        note="Command: " + command_line(), labels=2))
    if profiles:
        fig, ax = plt.subplots(figsize=(7, 4))
        x = np.linspace(-4.0, 4.0, 801)
        ax.plot(x, impinging_jet_wall(x)[1] / 0.5, "k", lw=2, label="Taylor (psph.analytic.impinging_jet_wall)")
        for label, ls, xs, p in profiles:
            ax.plot(xs, p, ls=ls, label=label)
        ax.set(xlabel="x / H", ylabel="p / (rho0 U^2 / 2)", title=f"Wall pressure, averaged over {window}")
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(args.out / "wall_pressure.png", dpi=150)
        plt.close(fig)
        plot_histories(args.out / "stagnation.png", curves, "t U / H", "p0 / (rho0 U^2 / 2)",
                       "Impinging jet: stagnation pressure (Taylor: 1)")


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
