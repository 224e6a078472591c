"""Elliptical drop from the lattice and after particle packing (seed 002 sections 2 and 3.4).

    .venv/bin/python run_scripts/elliptical_drop.py [--resolutions 20 40 80] [--ranks 2]
                                                   [--alphas 0.002 0.005 0.01 0.05] [--alpha-resolution 40]

Runs cases/elliptical_drop.toml (R = 1, A0 = 1, c0 = 20, to t A0 = 1) at each R/dx twice, from the
lattice (`packing.iterations=0`) and packed (the scene's packing), and compares the drop with its analytic
evolution (psph.analytic.EllipticalDrop): the semi-axes from the fluid's second moments and the RMS
pressure error in units of rho0 A0^2 R^2 / 2. Then sweeps the packing's damping alpha at one resolution,
every sweep run doing all 3000 iterations (packing.tolerance=1e-30), to show what the packing reaches for
its cost. Writes, in --out (results/elliptical_drop): drop.md/.csv, packing.md/.csv, axes.png (semi-axis
error against time), particles.png (the middle resolution's runs at t_end with the analytic ellipse) and packing.png
(T / beta and Linf(grad Gamma) h against the packing iteration, seed 002 fig. 6).
"""

import argparse
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from psph.initial import elliptical_drop  # noqa: E402
from psph.particles import Kind  # noqa: E402
from psph.scene.load import load_scene  # noqa: E402
from psph.studies import (  # noqa: E402
    CASES,
    at_time,
    command_line,
    last_snapshot,
    parse_args,
    plot_histories,
    positive_float,
    positive_int,
    run_scene,
    write_table,
)

SCENE = CASES / "elliptical_drop.toml"
SWEEP_ITERATIONS = 3000


def packing_rows(out) -> np.ndarray:
    """The packing history of a run: columns iteration, T / beta, Linf(grad Gamma) h."""
    return np.loadtxt(Path(out) / "packing.csv", delimiter=",", skiprows=1, ndmin=2)


def flow_runs(args):
    rows, runs = [], {}
    for n in args.resolutions:
        for start in ("lattice", "packed"):
            sets = [f"domain.dx={1.0 / n}", "output.every=0", "output.history_every=10"]
            if start == "lattice":
                sets.append("packing.iterations=0")
            run = run_scene(SCENE, args.out / f"{start}_r{n}", sets=sets, ranks=args.ranks)
            runs[(start, n)] = run
            h, packing = run.history, run.summary.get("packing", {})
            t_end = h[-1]["time"]
            pressure = np.mean([r["L2_pressure_error"] for r in h[1:]])
            rows.append([n, start, run.summary["n_particles"], packing.get("iterations", 0),
                         packing.get("time_s"), packing.get("Linf_grad_gamma_start"), packing.get("Linf_grad_gamma"),
                         h[0]["semi_axis_error"],
                         at_time(h, 0.5 * t_end, "semi_axis_error"), h[-1]["semi_axis_error"],
                         h[-1]["semi_axis_a"], h[-1]["semi_axis_b"], pressure, h[-1]["min_spacing"],
                         run.summary["wall_time_s"]])
            print(rows[-1], flush=True)
    return rows, runs


def sweep_runs(args):
    rows, histories = [], {}
    n = args.alpha_resolution
    for alpha in args.alphas:
        run = run_scene(SCENE, args.out / f"alpha{alpha:g}_r{n}", ranks=args.ranks,
                        sets=[f"domain.dx={1.0 / n}", f"packing.alpha={alpha}",
                              f"packing.iterations={SWEEP_ITERATIONS}", "packing.tolerance=1e-30",
                              "time.t_end=0.001", "output.every=0"],
                        settable=("time.t_end",))  # (its packing is measured, whatever t_end the run has)
        data = packing_rows(run.out)
        histories[alpha] = data
        linf = {int(it): value for it, _, value in data}
        rows.append([alpha, linf[0], linf[SWEEP_ITERATIONS // 3], linf[2 * SWEEP_ITERATIONS // 3],
                     linf[SWEEP_ITERATIONS], data[-1, 1], run.summary["packing"]["time_s"]])
        print(rows[-1], flush=True)
    return rows, histories


def plot_axes(path, runs):
    curves = [([r["time"] for r in run.history], [max(r["semi_axis_error"], 1e-6) for r in run.history],
               f"{start}, R/dx = {n}", {"ls": "--" if start == "lattice" else "-"})
              for (start, n), run in sorted(runs.items(), key=lambda kv: (kv[0][1], kv[0][0]))]
    plot_histories(path, curves, "t A0", "max(|a/a_exact - 1|, |b/b_exact - 1|)",
                   "Elliptical drop: semi-axis error (second moments)", logy=True)


def plot_particles(path, runs, n):
    fig, axes = plt.subplots(2, 1, figsize=(8, 4.5), sharex=True)
    for ax, start in zip(axes, ("lattice", "packed")):
        snap, t = last_snapshot(runs[(start, n)].out)
        pos = snap["position"][snap["kind"] == Kind.FLUID]
        drop = elliptical_drop(load_scene(SCENE, [f"domain.dx={1.0 / n}"]), t)
        a, b = drop.state(t)[:2]
        theta = np.linspace(0.0, 2.0 * np.pi, 400)
        ax.plot(pos[:, 0], pos[:, 1], ".", ms=1.5 * 40 / n, color="tab:blue")
        ax.plot(drop.center[0] + a * np.cos(theta), drop.center[1] + b * np.sin(theta), "k--", lw=0.8)
        ax.set(aspect="equal", ylim=(-0.6, 0.6), ylabel="y / R",
               title=f"{start} start, R/dx = {n}, t A0 = {t:g} (dashed: analytic)")
    axes[-1].set_xlabel("x / R")
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def plot_packing(path, histories, n):
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    for alpha, data in histories.items():
        ax1.semilogy(data[1:, 0], data[1:, 1], label=f"alpha = {alpha:g}")
        ax2.semilogy(data[:, 0], data[:, 2], label=f"alpha = {alpha:g}")
    ax1.set(xlabel="packing iteration", ylabel="T / beta", title=f"Drop, R/dx = {n}: kinetic energy")
    ax2.set(xlabel="packing iteration", ylabel="Linf(grad Gamma) h", title="with the frame particles")
    ax1.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/elliptical_drop"))
    parser.add_argument("--ranks", type=positive_int, default=1)
    parser.add_argument("--resolutions", type=positive_int, nargs="+", default=[20, 40, 80], help="R/dx")
    parser.add_argument("--alphas", type=positive_float, nargs="+", default=[0.002, 0.005, 0.01, 0.05])
    parser.add_argument("--alpha-resolution", type=positive_int, default=40, help="R/dx of the alpha sweep")
    args = parse_args(parser)
    rows, runs = flow_runs(args)
    note = "Command: " + command_line()
    print(write_table(args.out / "drop", [
        "R/dx", "start", "particles", "packing it.", "packing s", "Linf(grad Gamma) h lattice", "packed",
        "axes error t = 0",
        "t = 0.5", "t = 1", "a(1) / R", "b(1) / R", "RMS p error", "min spacing / dx (t = 1)", "wall s"], rows,
        title="Elliptical drop to t A0 = 1: semi-axis errors max(|a/a_exact - 1|, |b/b_exact - 1|), "
        "pressure error / (rho0 A0^2 R^2 / 2) averaged over the run", note=note))
    plot_axes(args.out / "axes.png", runs)
    plot_particles(args.out / "particles.png", runs, sorted(args.resolutions)[len(args.resolutions) // 2])
    if args.alphas:
        sweep, histories = sweep_runs(args)
        third = SWEEP_ITERATIONS // 3
        print(write_table(args.out / "packing", [
            "alpha", "Linf(grad Gamma) h, lattice", f"after {third} it.", f"{2 * third}", f"{SWEEP_ITERATIONS}",
            f"T / beta after {SWEEP_ITERATIONS}", "packing s"], sweep,
            title=f"Packing the drop at R/dx = {args.alpha_resolution}: Linf(grad Gamma) h with the frame particles",
            note=note))
        plot_packing(args.out / "packing.png", histories, args.alpha_resolution)


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
