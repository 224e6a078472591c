"""Hydrostatic column in a tank: the spurious velocity after t sqrt(g/H) = 10 (issue: walls and bodies).

    .venv/bin/python run_scripts/tank.py [--resolutions 20 40] [--walls clone ghost] [--t-end 10] [--ranks 1]

Runs cases/hydrostatic_tank.toml (water at rest, H = 1 deep in a 2 x 1.2 tank, free surface at y = 1,
g = 1, delta-ALE-SPH without shifting; run_scripts/free_surface.py adds shifting) at H/dx = 20 and 40
with clone walls (seed 004) and fixed ghost walls (seed 001, `bodies.0.model=ghost`), and writes, in --out
(results/tank): spurious.md and .csv (the largest particle speed at t_end and over the second half of the
run, in units of sqrt(g H); the largest density variation; the global volume error eps_V; the mass drift;
the wall time) and speed.png (the largest speed against time).
"""

import argparse
from pathlib import Path

import numpy as np

from psph.studies import CASES, command_line, plot_histories, run_scene, write_table


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/tank"))
    parser.add_argument("--ranks", type=int, default=1)
    parser.add_argument("--t-end", type=float, default=10.0, help="t sqrt(g/H)")
    parser.add_argument("--resolutions", type=int, nargs="+", default=[20, 40], help="H/dx")
    parser.add_argument("--walls", nargs="+", default=["clone", "ghost"], choices=["clone", "ghost"])
    args = parser.parse_args()
    rows, histories = [], {}
    for walls in args.walls:
        for n in args.resolutions:
            run = run_scene(CASES / "hydrostatic_tank.toml", args.out / f"{walls}_h{n}", ranks=args.ranks,
                            sets=[f"domain.dx={1.0 / n}", f"time.t_end={args.t_end}", "output.every=0",
                                  "output.history_every=20", f"bodies.0.model={walls}"])
            h = run.history
            t = np.array([r["time"] for r in h])
            speed = np.array([r["max_speed"] for r in h])
            mass = np.array([r["total_mass"] for r in h])
            late = t >= 0.5 * args.t_end
            rows.append([walls, n, run.summary["n_particles"], speed[-1], speed[late].max(),
                         max(r["max_density_variation"] for r in h), h[-1]["volume_error"],
                         float(np.abs(mass / mass[0] - 1.0).max()), run.summary["wall_time_s"]])
            histories[(walls, n)] = (t, speed)
            print(rows[-1], flush=True)
    curves = [(t, speed, f"{walls} walls, H/dx = {n}", {"ls": "-" if walls == "clone" else "--"})
              for (walls, n), (t, speed) in histories.items()]
    plot_histories(args.out / "speed.png", curves, "t sqrt(g/H)", "max |u| / sqrt(g H)",
                   "Hydrostatic tank: spurious velocity", logy=True)
    print(write_table(args.out / "spurious",
                      ["walls", "H/dx", "particles", f"max speed at t = {args.t_end:g}",
                       f"max speed, t >= {0.5 * args.t_end:g}", "max density variation", "eps_V(t_end)",
                       "max mass drift", "wall s"], rows,
                      title=f"Hydrostatic tank to t sqrt(g/H) = {args.t_end:g}: speeds in sqrt(g H)",
                      note="Command: " + command_line()))


if __name__ == "__main__":
    main()
