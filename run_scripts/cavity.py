"""Lid-driven cavity (seed 001 section 6.2): centreline velocities against Ghia, Ghia & Shin (1982) and
the global volume error eps_V(t) (seed 001 eq. 27, fig. 15).

    .venv/bin/python run_scripts/cavity.py [--re 100 1000] [--resolutions 50 100] [--t-end 20] [--ranks 2]
                                           [--walls clone ghost] [--ghost-resolutions 50] [--h-over-dx 1.5]

For each Reynolds number and L/dx it runs cases/lid_driven_cavity.toml to t_end (steady state), samples
u(y) on x = 0.5 and v(x) on y = 0.5 by kernel interpolation of the fluid particles at Ghia's points, and
writes results/cavity/{deviation.md,csv}, centrelines_Re*.png and volume_error.png. The reference data is
run_scripts/reference/ghia1982_Re100_Re1000.csv (provenance in its README). The clone-wall runs keep the
scene's shifting (IIPS + NFTS); --walls ghost also runs seed 001's baseline, fixed ghost particles
(model = "ghost") with delta+ shifting. The table's column "KE change, last fifth" says how steady the flow
is at t_end: the relative change of the kinetic energy over the run's last fifth.
"""

import argparse
import csv
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from psph.compute.smoothing import make_kernel  # noqa: E402
from psph.errors import PsphError  # noqa: E402
from psph.io.history import read_history  # noqa: E402
from psph.particles import Kind  # noqa: E402
from psph.scene.load import load_scene  # noqa: E402
from psph.studies import (  # noqa: E402
    CAVITY,
    CAVITY_WALLS,
    Run,
    RunStopped,
    command_line,
    last_snapshot,
    parse_args,
    positive_float,
    positive_int,
    run_scene,
    shepard_sample,
    shifting_label,
    smoothing_ratio,
    stop_message,
    write_histories,
    write_table,
)

GHIA = Path(__file__).resolve().parent / "reference" / "ghia1982_Re100_Re1000.csv"


def ghia(re):
    with open(GHIA) as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    col = lambda k: np.array([float(r[k]) for r in rows])  # noqa: E731
    return col("y"), col(f"u_Re{re}"), col("x"), col(f"v_Re{re}")


def ghia_reynolds() -> list:
    """The Reynolds numbers the reference data has both centrelines of."""
    with open(GHIA) as f:
        header = next(csv.reader(line for line in f if not line.startswith("#")))
    return sorted(int(k[4:]) for k in header if k.startswith("u_Re") and f"v_Re{k[4:]}" in header)


def centrelines(run, ratio, dx):
    snap, _ = last_snapshot(run.out)
    fluid = snap["kind"] == Kind.FLUID
    pos, vol, vel = snap["position"][fluid], snap["volume"][fluid], snap["velocity"][fluid]
    kernel = make_kernel("wendland_c6", 2, ratio * dx)
    sample = lambda pts: shepard_sample(pos, vol, vel, pts, kernel)  # noqa: E731
    return sample, pos, vel


def kinetic_energy_change(rows, fraction=0.2) -> float:
    """Relative change of the kinetic energy over the last `fraction` of the run's time: KE(t_end) / KE(t1) - 1
    with t1 the last history row at or before (1 - fraction) t_end. Near zero once the flow is steady; nan when
    that row is the fluid at rest (a run so short that the history's only row before t1 is t = 0's)."""
    t_end = rows[-1]["time"]
    start = [r for r in rows if r["time"] <= (1.0 - fraction) * t_end][-1]
    if start["kinetic_energy"] == 0.0:
        return float("nan")
    return rows[-1]["kinetic_energy"] / start["kinetic_energy"] - 1.0


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/cavity"))
    parser.add_argument("--ranks", type=positive_int, default=1)
    parser.add_argument("--t-end", type=positive_float, default=20.0)
    parser.add_argument("--re", type=positive_int, nargs="+", default=[100])
    parser.add_argument("--resolutions", type=positive_int, nargs="+", default=[50, 100], help="L/dx")
    parser.add_argument("--h-over-dx", type=smoothing_ratio, help="h/dx (default: the scene's, 2)")
    parser.add_argument("--walls", nargs="+", default=["clone"], choices=["clone", "ghost"])
    parser.add_argument("--ghost-resolutions", type=positive_int, nargs="+",
                        help="L/dx of the ghost runs (default: all)")
    parser.add_argument("--history-every", type=positive_int, default=50,
                        help="steps between history rows (output.history_every; the KE change reads them)")
    args = parse_args(parser)
    unknown = [re for re in args.re if re not in ghia_reynolds()]
    if unknown:  # (the comparison is the study: no run without it)
        parser.error(f"argument --re: no reference data for Re = {', '.join(map(str, unknown))} (Ghia et al. 1982 "
                     f"in {GHIA.name}: Re = {', '.join(map(str, ghia_reynolds()))})")
    for walls in args.walls:  # every wall model's scene is checked before the first run starts
        try:
            load_scene(CAVITY, [*CAVITY_WALLS[walls], *args.set])
        except PsphError as err:  # e.g. --set shifting.method=iips with ghost walls
            parser.error(f"{walls} walls: {err}")
    args.out.mkdir(parents=True, exist_ok=True)
    table, histories = [], {}
    for re in args.re:
        gy, gu, gx, gv = ghia(re)
        fig, (ax_u, ax_v) = plt.subplots(1, 2, figsize=(10, 4.5))
        ax_u.plot(gu, gy, "ko", label="Ghia et al. 1982")
        ax_v.plot(gx, gv, "ko", label="Ghia et al. 1982")
        for walls in args.walls:
            for n in (args.ghost_resolutions or args.resolutions) if walls == "ghost" else args.resolutions:
                dx = 1.0 / n
                name = f"Re{re}_L{n}" + ("" if walls == "clone" else f"_{walls}")
                ratio = args.h_over_dx if args.h_over_dx is not None else load_scene(CAVITY).domain.h_over_dx
                sets = [f"domain.dx={dx}", f"domain.h_over_dx={ratio}", f"physics.reynolds={re}",
                        f"time.t_end={args.t_end}", f"output.every={args.t_end}",
                        f"output.history_every={args.history_every}",
                        *CAVITY_WALLS[walls]]
                scene = load_scene(CAVITY, [*sets, *args.set])  # run_scene adds --set to the runs
                shifting = shifting_label(scene)
                try:
                    # the centrelines are sampled with the h/dx of the scene the run had (a --set of it too)
                    run = run_scene(CAVITY, args.out / name, sets=sets, ranks=args.ranks,
                                    settable=("domain.h_over_dx",))
                except RunStopped as err:  # psph's diagnosis stopped the run (its state and history are kept)
                    print(f"Re={re} {walls} L/dx={n}: stopped: {stop_message(err)}", flush=True)
                    table.append([re, walls, shifting, n,
                                  f"stopped: {stop_message(err).removeprefix('psph: error: ')}", *["-"] * 6])
                    if (args.out / name / "history.csv").exists():  # its histories up to the stop
                        histories[(re, walls, n)] = Run(args.out / name, {}, read_history(args.out / name /
                                                                                          "history.csv"))
                    continue
                sample, _, _ = centrelines(run, scene.domain.h_over_dx, dx)
                inner_y, inner_x = (gy > 0) & (gy < 1), (gx > 0) & (gx < 1)  # the walls' values are boundary data
                u = sample(np.stack([np.full(inner_y.sum(), 0.5), gy[inner_y]], 1))[:, 0]
                v = sample(np.stack([gx[inner_x], np.full(inner_x.sum(), 0.5)], 1))[:, 1]
                dev_u, dev_v = np.abs(u - gu[inner_y]).max(), np.abs(v - gv[inner_x]).max()
                rows = run.history
                eps = [r["volume_error"] for r in rows]
                mass = np.array([r["total_mass"] for r in rows])
                table.append([re, walls, shifting, n, dev_u, dev_v, max(dev_u, dev_v), eps[-1],
                              float(np.abs(mass / mass[0] - 1).max()), kinetic_energy_change(rows),
                              run.summary["wall_time_s"]])
                print(f"Re={re} {walls} L/dx={n}: max|u - u_Ghia| = {dev_u:.4f}, max|v - v_Ghia| = {dev_v:.4f}, "
                      f"eps_V(t_end) = {eps[-1]:.3e}", flush=True)
                line = np.linspace(0.0, 1.0, 201)
                label = f"psph {walls}, {shifting}, L/dx = {n}"
                ax_u.plot(sample(np.stack([np.full_like(line, 0.5), line], 1))[:, 0], line, label=label)
                ax_v.plot(line, sample(np.stack([line, np.full_like(line, 0.5)], 1))[:, 1], label=label)
                histories[(re, walls, n)] = run
        ax_u.set(xlabel="u / U", ylabel="y / L", title=f"u on x = 0.5, Re = {re}")
        ax_v.set(xlabel="x / L", ylabel="v / U", title=f"v on y = 0.5, Re = {re}")
        ax_u.legend()
        fig.tight_layout()
        fig.savefig(args.out / f"centrelines_Re{re}.png", dpi=120)
        plt.close(fig)
    write_histories(args.out / "histories.csv", ["Re", "walls", "L/dx"], histories.items(),
                    ["volume_error", "total_mass", "kinetic_energy"])
    fig, ax = plt.subplots(figsize=(6, 4))
    for (re, walls, n), run in histories.items():
        t, eps = [r["time"] for r in run.history], [r["volume_error"] for r in run.history]
        ax.plot(t, eps, label=f"Re = {re}, {walls}, L/dx = {n}")
    ax.set(xlabel="t U / L", ylabel="eps_V", title="global volume error (seed 001 eq. 27)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out / "volume_error.png", dpi=120)
    print(write_table(args.out / "deviation",
                      ["Re", "walls", "shifting", "L/dx", "max dev. u", "max dev. v", "max dev.", "eps_V(t_end)",
                       "max mass drift", "KE change, last fifth", "wall s"], table,
                      title=f"Lid-driven cavity at t = {args.t_end}: deviation from Ghia et al. (1982), in U",
                      note="Command: " + command_line()))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
