"""Dam-break flow impacting a vertical wall (seed 001 section 6.3): the initial pressure against the
incompressible solution, the surge front, the impact on the wall, the energy and the conservation.

    .venv/bin/python run_scripts/dam_break.py [--resolutions 20 40] [--t-end 8] [--ranks 2]
        [--early-resolutions 20 40] [--early-sound-speeds 20 40 80] [--impact-resolutions 80]

Runs cases/dam_break.toml (a column H high and B = 2 H long released in a tank 5.367 H long; delta-ALE-SPH,
delta-plus shifting, artificial viscosity alpha = 0.01, c0 = 20 sqrt(g H)) and writes, in --out
(results/dam_break):

- initial_pressure.md/.csv: the pressure just after the release, averaged over t sqrt(g/H) in [0, 0.2] at nine
  points inside the column (x = 0.5, 1, 1.5 H; y = 0.25, 0.5, 0.75 H), against the incompressible fluid's
  initial pressure (analytic.dam_break_initial), RMS and largest error in rho0 g H. The release sends sound
  through the column, which the average removes; the larger c0 the shorter its periods against the flow's
  own evolution. The hydrostatic pressure the run starts from is the row "start";
- impact.md/.csv: the surge and the first impact against resolution, up to t = 3: the runs below cut there
  and runs to t = 3 only at --impact-resolutions (80: 18 204 particles). The front at t = 1 and 2 against
  the column's length B plus Ritter's 2 sqrt(g H) t (dry-bed shallow water: an upper bound, the
  experiments' fronts are slower), the time the front reaches the right wall, probe P1's first pressure
  peak (on the right wall 0.01 H above the bottom) and its time, averaged over 0.1 sqrt(H/g) and raw (the
  raw signal carries the sound of the impact), P1's mean over t = 2.7-3 (the run-up pressing on the wall
  after the impact's sound), the largest density variation, how many times a particle
  crossed the tank's walls and was mirrored back (WallTerms.reflect), the wall time;
- dam_break.md/.csv: per resolution, the runs to --t-end: P1's largest pressure after t = 5 (the plunging
  wave's return; raw, it carries the sound of an air cavity's collapse, rho0 c0 |u|), the energy
  dissipated by t_end as a fraction of the potential energy that can be released (the column's against the
  final flat layer's), the mass drift, eps_V, the largest density variation, the wall reflections and the
  wall time;
- front.png, p1.png, impact.png (P1 from t = 2.2 to 3 at every resolution), energy.png (and histories.csv
  with the plotted columns of the runs to --t-end), snapshots.png (the pressure at t = 1 .. 8 at the finest
  resolution).
"""

import argparse
from pathlib import Path

import numpy as np
from scipy.integrate import trapezoid

from psph.io.snapshots import snapshot_files
from psph.particles import Kind
from psph.studies import (
    CASES,
    DAM_BREAK_PROBES,
    command_line,
    parse_args,
    plot_histories,
    positive_float,
    positive_int,
    release_pressure_errors,
    run_scene,
    write_histories,
    write_table,
)

H, B, L = 1.0, 2.0, 5.367  # cases/dam_break.toml: column height and length, tank length (rho0 = g = 1)
EARLY_END = 0.2
IMPACT_END = 3.0  # past the first impact (t = 2.4-2.6) and the run-up's start
AFTER_IMPACT = 0.3  # P1's mean over the last 0.3 sqrt(H/g) before IMPACT_END: the run-up's pressure on the wall
SMOOTHING = 0.1  # sqrt(H/g): P1's average, over the sound the impacts send through the flow (c0 = 20 sqrt(g H)
# crosses the 2 H deep run-up in 0.1)


def early_pressure(args):
    """Rows of initial_pressure.md: (H/dx, c0, RMS and largest error of the time-averaged pressure, the
    pressure's largest swing, wall time); the first row the hydrostatic start's errors."""
    rows = []
    for n in args.early_resolutions:
        for c0 in args.early_sound_speeds:
            run = run_scene(CASES / "dam_break.toml", args.out / f"early_h{n}_c{c0:g}", ranks=args.ranks,
                            sets=[f"domain.dx={H / n}", f"physics.sound_speed={c0}", f"time.t_end={EARLY_END}",
                                  "output.every=0", "output.history_every=1", DAM_BREAK_PROBES])
            error, start, swing = release_pressure_errors(run.out)
            if not rows:
                rows.append(["start", "-", float(np.sqrt(np.mean(start**2))), float(np.abs(start).max()), "-", "-"])
            rows.append([n, c0, float(np.sqrt(np.mean(error**2))), float(np.abs(error).max()), float(swing.max()),
                         run.summary["wall_time_s"]])
            print(rows[-1], flush=True)
    return rows


def impact_row(n, run, end=IMPACT_END):
    """Row of impact.md from a run's history and probes up to t = end: H/dx, particles, the front at t = 1
    and 2, when it reaches the right wall, P1's first peak (averaged over SMOOTHING, its time, raw), the
    mean over t = end - AFTER_IMPACT .. end, the largest density variation, the wall reflections."""
    h = [r for r in run.history if r["time"] <= end + 1e-9]
    t = np.array([r["time"] for r in h])
    front = np.array([r["front_x"] for r in h])
    probe = np.genfromtxt(run.out / "probes.csv", delimiter=",", names=True)
    keep = probe["time"] <= end + 1e-9
    tp, p1 = probe["time"][keep], np.nan_to_num(probe["p_0"][keep], nan=0.0)
    ts, p1s = smoothed(tp, p1)
    after = tp >= end - AFTER_IMPACT
    return [n, run.summary["n_particles"], float(np.interp(1.0, t, front)), B + 2.0, float(np.interp(2.0, t, front)),
            B + 4.0, first_time(t, front, L - H / n), float(p1s.max()), float(ts[np.argmax(p1s)]), float(p1.max()),
            float(trapezoid(p1[after], tp[after]) / (tp[after][-1] - tp[after][0])),
            max(r["max_density_variation"] for r in h), h[-1]["wall_reflections"]]


def smoothed(t, values, width=SMOOTHING):
    """values(t) on a uniform grid of the same number of samples, averaged over a sliding window `width`
    long (nan read as 0: P1 is dry before the front arrives)."""
    grid = np.linspace(t[0], t[-1], len(t))
    window = np.ones(min(len(t), max(1, int(round(width / (grid[1] - grid[0]))))))
    total = np.convolve(np.interp(grid, t, np.nan_to_num(values, nan=0.0)), window, "same")
    return grid, total / np.convolve(np.ones(len(t)), window, "same")  # the ends average what they have


def first_time(t, values, threshold):
    above = np.nonzero(values >= threshold)[0]
    return float(t[above[0]]) if above.size else float("nan")


def snapshots_figure(path, out, times):
    """The fluid's pressure at `times` (the snapshots nearest them) in one figure."""
    import h5py
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = snapshot_files(out)
    stamps = []
    for f in files:
        with h5py.File(f) as h:
            stamps.append(float(h.attrs["time"]))
    fig, axes = plt.subplots(len(times) // 2, 2, figsize=(11, 1.05 * len(times)))
    for ax, want in zip(axes.flat, times):
        with h5py.File(files[int(np.argmin(np.abs(np.array(stamps) - want)))]) as h:
            pos, p, kind, t = (h["particles/position"][:], h["particles/pressure"][:], h["particles/kind"][:],
                               float(h.attrs["time"]))
        fluid = kind == int(Kind.FLUID)
        art = ax.scatter(pos[fluid, 0], pos[fluid, 1], c=p[fluid], s=0.4, cmap="viridis", vmin=0.0, vmax=1.0)
        ax.scatter(pos[~fluid, 0], pos[~fluid, 1], c="0.7", s=0.2)
        ax.set(xlim=(-0.15, L + 0.15), ylim=(-0.15, 2.2), aspect="equal", title=f"t sqrt(g/H) = {t:.2f}")
        ax.tick_params(labelsize=7)
    fig.colorbar(art, ax=axes, shrink=0.6, label="p / (rho0 g H)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/dam_break"))
    parser.add_argument("--ranks", type=positive_int, default=2)
    parser.add_argument("--t-end", type=positive_float, default=8.0, help="t sqrt(g/H)")
    parser.add_argument("--resolutions", type=positive_int, nargs="*", default=[20, 40],
                        help="H/dx of the runs to --t-end")
    parser.add_argument("--early-resolutions", type=positive_int, nargs="+", default=[20, 40], help="H/dx")
    parser.add_argument("--early-sound-speeds", type=positive_float, nargs="+", default=[20.0, 40.0, 80.0],
                        help="c0 / sqrt(g H) of the initial-pressure runs")
    parser.add_argument("--impact-resolutions", type=positive_int, nargs="*", default=[80],
                        help=f"H/dx of runs to t = {IMPACT_END:g} only (the surge and the first impact)")
    args = parse_args(parser)
    if args.resolutions and args.t_end < IMPACT_END:  # the table of the runs to --t-end reads the first impact
        parser.error(f"--t-end {args.t_end:g} ends before the first impact's window (t = {IMPACT_END:g}); for "
                     "shorter runs give --resolutions with no value")
    note = "Command: " + command_line()
    print(write_table(args.out / "initial_pressure",
                      ["H/dx", "c0 / sqrt(gH)", "RMS error", "max error", "largest swing", "wall s"],
                      early_pressure(args),
                      title=f"Pressure averaged over t sqrt(g/H) in [0, {EARLY_END:g}] at nine points inside the "
                            "column against the incompressible initial pressure, in rho0 g H", note=note))
    rows, runs = [], []
    released = 0.5 * B * H * H - 0.5 * L * (B * H / L) ** 2  # potential energy of the column over the flat layer
    for n in args.resolutions:
        run = run_scene(CASES / "dam_break.toml", args.out / f"h{n}", ranks=args.ranks,
                        sets=[f"domain.dx={H / n}", f"time.t_end={args.t_end}", "output.every=0.25",
                              "output.history_every=5"])
        h = run.history
        energy = np.array([r["kinetic_energy"] + r["potential_energy"] for r in h])
        mass = np.array([r["total_mass"] for r in h])
        probe = np.genfromtxt(run.out / "probes.csv", delimiter=",", names=True)
        tp, p1 = probe["time"], np.nan_to_num(probe["p_0"], nan=0.0)
        ts, p1s = smoothed(tp, p1)
        late = ts >= 5.0
        rows.append([n, run.summary["n_particles"], float(p1s[late].max()) if late.any() else float("nan"),
                     float(p1[tp >= 5.0].max()) if late.any() else float("nan"),
                     float((energy[0] - energy[-1]) / released), float(np.abs(mass / mass[0] - 1.0).max()),
                     h[-1]["volume_error"], max(r["max_density_variation"] for r in h), h[-1]["wall_reflections"],
                     run.summary["wall_time_s"]])
        runs.append(((n,), run))
        print(rows[-1], flush=True)
    impact, short = [impact_row(n, run) + ["-"] for (n,), run in runs], []
    for n in args.impact_resolutions:
        run = run_scene(CASES / "dam_break.toml", args.out / f"impact_h{n}", ranks=args.ranks,
                        sets=[f"domain.dx={H / n}", f"time.t_end={IMPACT_END}", "output.every=0.25",
                              "output.history_every=5"])
        short.append(((n,), run))
        impact.append(impact_row(n, run) + [run.summary["wall_time_s"]])
        print(impact[-1], flush=True)
    print(write_table(args.out / "impact",
                      ["H/dx", "particles", "front at t = 1", "B + 2 t (Ritter)", "front at t = 2", "B + 2 t",
                       "front at the wall, t", f"P1 first peak, {SMOOTHING:g} average", "at t",
                       "P1 first peak, raw", f"P1 mean, t = {IMPACT_END - AFTER_IMPACT:g}-{IMPACT_END:g}",
                       "max density variation", "wall reflections",
                       f"wall s (runs to t = {IMPACT_END:g})"], impact,
                      title=f"Dam break up to t = {IMPACT_END:g} sqrt(H/g): the surge and the first impact against "
                            "resolution (the runs below cut there, and runs to that time only); t in sqrt(H/g), "
                            "lengths in H, the front from the back wall, pressures in rho0 g H", note=note))
    if rows:  # (none with --resolutions given no value: the runs to --t-end are the table)
        print(write_table(args.out / "dam_break",
                          ["H/dx", "particles", "P1 max t >= 5, average", "raw",
                           f"energy dissipated by t = {args.t_end:g}", "max mass drift", "eps_V(t_end)",
                           "max density variation", "wall reflections", "wall s"], rows,
                          title=f"Dam break to t = {args.t_end:g} sqrt(H/g): the plunging wave, the energy, the "
                                "conservation; pressures in rho0 g H, the dissipated energy over the potential "
                                "energy the collapse can release", note=note))
    styles = {n: {"lw": 1.0 + 0.5 * k} for k, n in enumerate(args.resolutions + args.impact_resolutions)}
    curves = [(np.array([r["time"] for r in run.history]), np.array([r["front_x"] for r in run.history]),
               f"H/dx = {n}", styles[n]) for (n,), run in runs + short]
    ritter = np.linspace(0.0, (L - B) / 2.0, 20)
    curves.append((ritter, B + 2.0 * ritter, "B + 2 sqrt(gH) t (Ritter)", {"ls": "--", "color": "k"}))
    plot_histories(args.out / "front.png", curves, "t sqrt(g/H)", "front x / H", "Dam break: surge front")
    curves = []
    for (n,), run in runs:
        probe = np.genfromtxt(run.out / "probes.csv", delimiter=",", names=True)
        curves.append((probe["time"], probe["p_0"], f"H/dx = {n}", {**styles[n], "alpha": 0.3}))
        curves.append((*smoothed(probe["time"], probe["p_0"]), f"H/dx = {n}, {SMOOTHING:g} average", styles[n]))
    plot_histories(args.out / "p1.png", curves, "t sqrt(g/H)", "p / (rho0 g H)",
                   "Dam break: pressure at P1 (right wall, y = 0.01 H)")
    curves = []
    for (n,), run in runs + short:
        probe = np.genfromtxt(run.out / "probes.csv", delimiter=",", names=True)
        t, p1 = probe["time"], np.nan_to_num(probe["p_0"], nan=0.0)
        keep = t <= IMPACT_END + 1e-9
        ts, p1s = smoothed(t[keep], p1[keep])
        shown, shown_s = (t >= 2.2) & keep, ts >= 2.2
        curves.append((t[shown], p1[shown], f"H/dx = {n}", {**styles[n], "alpha": 0.3}))
        curves.append((ts[shown_s], p1s[shown_s], f"H/dx = {n}, {SMOOTHING:g} average", styles[n]))
    plot_histories(args.out / "impact.png", curves, "t sqrt(g/H)", "p / (rho0 g H)",
                   "Dam break: the first impact at P1")
    curves = [(np.array([r["time"] for r in run.history]),
               np.array([r["kinetic_energy"] + r["potential_energy"] for r in run.history]), f"H/dx = {n}",
               styles[n]) for (n,), run in runs]
    plot_histories(args.out / "energy.png", curves, "t sqrt(g/H)", "E_k + E_p / (rho0 g H^3)",
                   "Dam break: kinetic + potential energy")
    write_histories(args.out / "histories.csv", ["H/dx"], runs,
                    ["front_x", "column_height", "kinetic_energy", "potential_energy", "volume_error",
                     "total_mass", "max_density_variation", "wall_reflections"])
    if runs:
        snapshots_figure(args.out / "snapshots.png", runs[-1][1].out, np.arange(1.0, 9.0))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
