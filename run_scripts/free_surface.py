"""Shifting with a free surface: the elliptical drop and the hydrostatic tank, without shifting, with the
delta+ law and with IIPS, the free surface detected (psph.boundaries.free_surface).

    .venv/bin/python run_scripts/free_surface.py [--drop-resolutions 20 40 80] [--tank-resolutions 20 40]
                                                 [--methods none delta_plus iips] [--ranks 2] [--no-run]

Drop: cases/elliptical_drop.toml (packed, R = 1, A0 = 1, c0 = 20, to t A0 = 1) at each R/dx; the semi-axis
error max(|a/a_exact - 1|, |b/b_exact - 1|) from the fluid's second moments and the RMS pressure error in
units of rho0 A0^2 R^2 / 2 (averaged over the run), against psph.analytic.EllipticalDrop.
Tank: cases/hydrostatic_tank.toml (water at rest, clone walls, to t sqrt(g/H) = 10): the largest particle
speed in units of sqrt(g H).
IIPS runs as the thesis runs it with a free surface (section 10.2.2): Procedure A, threshold
Linf(grad C) = 0.02, the NFTS field update. Writes, in --out (results/free_surface): drop.md/.csv,
tank.md/.csv, drop_axes.png and tank_speed.png (against time), surface.png (the finest delta+ drop at
t_end, coloured by the detection's flags). --no-run builds them from the finished runs in --out only.
"""

import argparse
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from psph.compute.free_surface import REGION, SURFACE  # noqa: E402
from psph.particles import Kind  # noqa: E402
from psph.studies import (  # noqa: E402
    CASES,
    NotRun,
    at_time,
    command_line,
    last_snapshot,
    parse_args,
    plot_histories,
    positive_int,
    run_scene,
    write_table,
)

IIPS = ["shifting.method=iips", "iips.procedure=A", "iips.threshold=0.02", "iips.update=nfts"]
METHODS = {"none": ["shifting.method=none"], "delta_plus": ["shifting.method=delta_plus"], "iips": IIPS}


def finished_run(args, scene, out, sets):
    """run_scene, or None (reported) for a run --no-run does not find finished."""
    try:
        return run_scene(CASES / scene, out, ranks=args.ranks, sets=sets, only_finished=args.no_run)
    except NotRun:
        print(f"{out}: not run", flush=True)
        return None


def sweep(args, scene, name, resolutions, history_every, row_of):
    """Every method at every resolution of one scene, each run in --out/name.format(method=, n=): (rows, with
    row_of(history) in the middle, {(method, n): run})."""
    rows, runs = [], {}
    for n in resolutions:
        for method in args.methods:
            run = finished_run(args, scene, args.out / name.format(method=method, n=n),
                               [f"domain.dx={1.0 / n}", "output.every=0", f"output.history_every={history_every}",
                                *METHODS[method]])
            if run is None:
                continue
            runs[(method, n)] = run
            rows.append([n, method, *row_of(run.history), *interior_linf(run.history), run.summary["wall_time_s"]])
            print(rows[-1], flush=True)
    return rows, runs


def drop_row(h) -> list:
    """Axes error at t_end / 2 and t_end, b's error at t_end, mean pressure error, final smallest spacing."""
    return [at_time(h, 0.5 * h[-1]["time"], "semi_axis_error"), h[-1]["semi_axis_error"],
            h[-1]["semi_axis_b"] / h[-1]["semi_axis_b_exact"] - 1.0,
            np.mean([r["L2_pressure_error"] for r in h[1:]]), h[-1]["min_spacing"]]


def tank_row(h) -> list:
    """Largest speed at t_end and over the second half of the run, final volume error."""
    t = np.array([r["time"] for r in h])
    speed = np.array([r["max_speed"] for r in h])
    return [speed[-1], speed[t >= 0.5 * t[-1]].max(), h[-1]["volume_error"]]


def interior_linf(history) -> list:
    """[mean Linf(grad C) over the interior, surface particles at the end], blank without detection (the
    history's grad C then includes the surface's)."""
    if "surface_particles" not in history[-1]:
        return ["", ""]
    return [np.mean([r["Linf_grad_c"] for r in history[1:]]), history[-1]["surface_particles"]]


def plot_surface(path, run, n):
    snap, t = last_snapshot(run.out)
    fluid = snap["kind"] == Kind.FLUID
    pos, flag = snap["position"][fluid], snap["free_surface"][fluid]
    fig, ax = plt.subplots(figsize=(9, 3))
    for value, colour, label in ((0, "tab:blue", "interior"), (REGION, "tab:orange", "region (no normal shift)"),
                                 (SURFACE, "tab:red", "surface")):
        sel = flag == value
        ax.plot(pos[sel, 0], pos[sel, 1], ".", ms=2.0 * 40 / n, color=colour, label=label)
    ax.set(aspect="equal", xlabel="x / R", ylabel="y / R",
           title=f"Drop with delta+, R/dx = {n}, t A0 = {t:g}: free-surface detection")
    ax.legend(fontsize=7, loc="upper right", markerscale=3)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/free_surface"))
    parser.add_argument("--ranks", type=positive_int, default=2)
    parser.add_argument("--drop-resolutions", type=positive_int, nargs="*", default=[20, 40, 80], help="R/dx")
    parser.add_argument("--tank-resolutions", type=positive_int, nargs="*", default=[20, 40], help="H/dx")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--no-run", action="store_true", help="tables and plots from the finished runs only")
    args = parse_args(parser)
    note = "Command: " + command_line()
    if args.drop_resolutions:
        rows, runs = sweep(args, "elliptical_drop.toml", "drop_{method}_r{n}", args.drop_resolutions, 10, drop_row)
        print(write_table(args.out / "drop", [
            "R/dx", "shifting", "axes error t = 0.5", "t = 1", "b/b_exact - 1 (t = 1)", "RMS p error",
            "min spacing / dx (t = 1)", "interior Linf(grad C), mean", "surface particles (t = 1)", "wall s"],
            rows, title="Elliptical drop (packed) to t A0 = 1 with a detected free surface", note=note, labels=2))
        curves = [([r["time"] for r in run.history], [max(r["semi_axis_error"], 1e-6) for r in run.history],
                   f"{method}, R/dx = {n}", {"ls": {"none": ":", "delta_plus": "-", "iips": "--"}[method]})
                  for (method, n), run in sorted(runs.items(), key=lambda kv: (kv[0][1], kv[0][0]))]
        plot_histories(args.out / "drop_axes.png", curves, "t A0", "max(|a/a_exact - 1|, |b/b_exact - 1|)",
                       "Elliptical drop: semi-axis error", logy=True)
        finest = [n for (method, n) in runs if method == "delta_plus"]
        if finest:
            plot_surface(args.out / "surface.png", runs[("delta_plus", max(finest))], max(finest))
    if args.tank_resolutions:
        rows, runs = sweep(args, "hydrostatic_tank.toml", "tank_{method}_h{n}", args.tank_resolutions, 20, tank_row)
        print(write_table(args.out / "tank", [
            "H/dx", "shifting", "max speed at t = 10", "max speed, t >= 5", "eps_V(t_end)",
            "interior Linf(grad C), mean", "surface particles (t_end)", "wall s"], rows,
            title="Hydrostatic tank (clone walls) to t sqrt(g/H) = 10: speeds in sqrt(g H)", note=note, labels=2))
        curves = [([r["time"] for r in run.history], [max(r["max_speed"], 1e-8) for r in run.history],
                   f"{method}, H/dx = {n}", {"ls": {"none": ":", "delta_plus": "-", "iips": "--"}[method]})
                  for (method, n), run in sorted(runs.items(), key=lambda kv: (kv[0][1], kv[0][0]))]
        plot_histories(args.out / "tank_speed.png", curves, "t sqrt(g/H)", "max |u| / sqrt(g H)",
                       "Hydrostatic tank: spurious velocity", logy=True)


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
