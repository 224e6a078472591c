"""Flow past an inclined elliptical cylinder at Re = 500 (seed 001 section 6.1): viscous drag histories
(fig. 3), particle volume and mass variation fields (fig. 4-5) and the global volume error (fig. 7).

    .venv/bin/python run_scripts/ellipse.py [--resolutions 25 50] [--t-end 50] [--ranks 2]

For each a/dx it runs cases/inclined_ellipse.toml to t_end and writes, in --out (results/ellipse):
forces.md and .csv (the mean viscous drag before the wake comes back to the ellipse through the periodic
box, at t U/a = 14, and over the second half of the run: mean coefficients, the viscous drag's range
and the Strouhal number St = f a / U of the lift's dominant frequency, studies.dominant_frequency);
drag.png (cd_viscous, cd_pressure, cl against t U/a); variations_a{N}.png (eps_Vi = V_i/V0 - 1 and
eps_mi = m_i/m0 - 1 around the ellipse at t_end); volume_error.png. Seed 001 compares with the DVH
solution of Rossi et al. (2015), which is not in ../shared/reference: the resolutions are compared with
each other.

--in-progress tabulates a run still going (or stopped before t_end) from what its directory holds: the
history so far, and the latest checkpoint's particles for the variation fields (a column gives the time
reached). The runs take hours: a finished run of the study's own command is always read back, and a
directory holding any other run (one in progress, or resumed by hand) stops the study instead of being
run over, unless --rerun is given. `--in-progress` never starts a run.
"""

import argparse
from pathlib import Path

import h5py
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from psph.particles import Kind  # noqa: E402
from psph.studies import (  # noqa: E402
    CASES,
    after,
    command_line,
    dominant_frequency,
    last_snapshot,
    long_run,
    mean_after,
    parse_args,
    plot_histories,
    positive_float,
    positive_int,
    write_histories,
    write_table,
)


def wake_return_time(scene):
    """When the wake shed at the start first comes back to the body through the periodic box: the box's
    length along the free stream over its speed (the flow is not an unbounded one after that)."""
    u = np.asarray(scene["physics"]["free_stream"], dtype=float)
    length = np.asarray(scene["domain"]["upper"]) - np.asarray(scene["domain"]["lower"])
    return float(abs(length @ u) / (u @ u))


def latest_state(run):
    """(particle fields, time) of the run's last snapshot, or of its latest checkpoint when that is later."""
    snap, t = last_snapshot(run.out)
    checkpoints = sorted(run.out.glob("checkpoint_*.h5"))
    if checkpoints:
        with h5py.File(checkpoints[-1]) as f:
            if float(f.attrs["time"]) > t:
                return {k: f["particles"][k][:] for k in f["particles"]}, float(f.attrs["time"])
    return snap, t


def plot_variations(run, n, rho0, path):
    snap, t = latest_state(run)
    fluid = snap["kind"] == Kind.FLUID
    pos = snap["position"][fluid]
    dx = 1.0 / n
    eps_v = snap["volume"][fluid] / snap["volume0"][fluid] - 1.0  # V0 = dx^2 (a Cartesian lattice)
    eps_m = snap["mass"][fluid] / (rho0 * dx ** 2) - 1.0  # m0 = rho0 dx^2 (seed 001 fig. 5)
    fig, axes = plt.subplots(2, 1, figsize=(10, 7.5), sharex=True)
    for ax, eps, name in ((axes[0], eps_v, "eps_V = V/V0 - 1"), (axes[1], eps_m, "eps_m = m/m0 - 1")):
        lim = max(np.percentile(np.abs(eps), 99.5), 1e-12)
        sc = ax.scatter(pos[:, 0], pos[:, 1], c=eps, s=2.0 * (25.0 / n) ** 2, cmap="RdBu_r", vmin=-lim, vmax=lim,
                        rasterized=True)
        fig.colorbar(sc, ax=ax, label=name)
        ax.set(xlim=(2.0, 14.0), ylim=(2.0, 8.0), aspect="equal", ylabel="y / a",
               title=f"{name} at t U/a = {t:.3g}, a/dx = {n}")
    axes[1].set_xlabel("x / a")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return float(np.abs(eps_v).max()), float(np.abs(eps_m).max())


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/ellipse"))
    parser.add_argument("--ranks", type=positive_int, default=1)
    parser.add_argument("--t-end", type=positive_float, default=50.0)
    parser.add_argument("--resolutions", type=positive_int, nargs="+", default=[25, 50], help="a/dx")
    parser.add_argument("--in-progress", action="store_true",
                        help="tabulate finished runs and, for the others, what they have written so far")
    parser.add_argument("--rerun", action="store_true",
                        help="run every resolution again, over what its directory holds")
    args = parse_args(parser)
    args.out.mkdir(parents=True, exist_ok=True)
    runs, table, partial = {}, [], []
    for n in args.resolutions:
        sets = [f"domain.dx={1.0 / n}", f"time.t_end={args.t_end}", f"output.every={args.t_end / 5}",
                "output.history_every=20", "output.checkpoint_minutes=15"]
        out = args.out / f"a{n}"
        run = long_run(CASES / "inclined_ellipse.toml", out, sets, args.ranks, args.in_progress, args.rerun)
        if run.history[-1]["time"] < args.t_end * (1.0 - 1e-12):
            partial.append(n)
        runs[n] = run
        rows = run.history
        mass = np.array([r["total_mass"] for r in rows])
        rho0 = run.summary["scene"]["physics"]["density"]
        eps_vi, eps_mi = plot_variations(run, n, rho0, args.out / f"variations_a{n}.png")
        t0, t_wake = 0.5 * args.t_end, wake_return_time(run.summary["scene"])
        early = (0.5 * min(args.t_end, t_wake), t_wake)
        cdv = after(rows, "cd_viscous", t0)
        table.append([n, run.summary["n_particles"], mean_after(rows, "cd_viscous", *early),
                      mean_after(rows, "cd_viscous", t0),
                      f"{cdv.min():.3g}-{cdv.max():.3g}" if cdv.size else "-", mean_after(rows, "cd_pressure", t0),
                      mean_after(rows, "cl", t0), dominant_frequency(after(rows, "time", t0), after(rows, "cl", t0)),
                      rows[-1]["volume_error"], eps_vi, eps_mi, float(np.abs(mass / mass[0] - 1).max()),
                      rows[-1]["step_time_s"], rows[-1]["time"]])
        print(f"a/dx={n}: mean cd_viscous {table[-1][2]:.4f} over {early[0]:g} <= t <= {early[1]:g}, "
              f"{table[-1][3]:.4f} over t >= {t0:g}", flush=True)
    write_histories(args.out / "histories.csv", ["a/dx"], [((n,), run) for n, run in runs.items()],
                    ["cd_viscous", "cd_pressure", "cl_viscous", "cl_pressure", "volume_error", "total_mass"])
    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    for n, run in runs.items():
        t = [r["time"] for r in run.history]
        for ax, key in zip(axes, ("cd_viscous", "cd_pressure", "cl")):
            ax.plot(t, after(run.history, key, 0.0), label=f"a/dx = {n}")
    for ax, name in zip(axes, ("viscous drag cd_viscous", "pressure drag cd_pressure", "lift cl")):
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[0].set_ylim(0.0, None)
    if t_wake < args.t_end:
        for ax in axes:
            ax.axvline(t_wake, color="0.5", ls=":", label="the wake returns (periodic box)" if ax is axes[0] else None)
    axes[0].legend()
    axes[0].set_title("Inclined ellipse, Re = 500, 20 degrees (seed 001 fig. 3): coefficients 2F/(rho0 U^2 a)")
    axes[-1].set_xlabel("t U / a")
    fig.tight_layout()
    fig.savefig(args.out / "drag.png", dpi=120)
    plt.close(fig)
    plot_histories(args.out / "volume_error.png",
                   [([r["time"] for r in run.history], [r["volume_error"] for r in run.history], f"a/dx = {n}", {})
                    for n, run in runs.items()],
                   "t U / a", "eps_V", "global volume error (seed 001 eq. 27, fig. 7)", size=(6, 4))
    print(write_table(args.out / "forces",
                      ["a/dx", "particles", f"mean cd_viscous ({early[0]:g} <= t <= {early[1]:g})",
                       f"mean cd_viscous (t >= {t0:g})", "cd_viscous range", "mean cd_pressure", "mean cl",
                       "St = f a / U (lift)", "eps_V (last)", "max |eps_Vi|", "max |eps_mi|", "max mass drift",
                       "time-step loop s (all segments)", "t U/a reached"],
                      table, title=f"Inclined ellipse, Re = 500, to t U/a = {args.t_end:g}",
                      note=f"t U/a = {t_wake:g}: the box's length over U, when the wake first comes back to the "
                           "ellipse through the periodic box. "
                           + (f"a/dx = {', '.join(map(str, partial))}: a run in progress, tabulated to the time it "
                              "reached (its windows end there). " if partial else "") + "Command: " + command_line()))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
