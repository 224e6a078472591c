"""Water at rest in a tank: the spurious velocity and the pressure's error (issue: walls and bodies;
seed 002 section 3.1 for the trapezoidal tank).

    .venv/bin/python run_scripts/tank.py [--tanks box trapezoid] [--resolutions 20 40]
        [--trapezoid-resolutions 25 50] [--walls clone ghost] [--schemes delta_ale riemann_ale riemann_low]
        [--t-end 10] [--ranks 1]

Runs cases/hydrostatic_tank.toml (water at rest, H = 1 deep in a 2 x 1.2 tank, free surface at y = 1,
g = 1, delta-ALE-SPH without shifting; run_scripts/free_surface.py adds shifting) at H/dx = 20 and 40
with clone walls (seed 004) and fixed ghost walls (seed 001, `bodies.0.model=ghost`), and
cases/trapezoidal_tank.toml (the same water in a tank whose right wall is inclined, clone walls only:
ghost walls need an axis-aligned box) at H/dx = 25 and 50, as seed 002 fig. 8; with --schemes, in the
Riemann SPH-ALE scheme too (riemann_low: its low-dissipation pressure; README, "Walls in the Riemann
scheme"). Writes, in --out (results/tank): spurious.md and .csv (the largest particle speed at t_end and
over the second half of the run, in units of sqrt(g H); the RMS and largest deviation of the fluid's
pressure from the hydrostatic rho0 g (H - y) at t_end, in rho0 g H, and its largest below y = 0.3 H; the
largest relative error over the second half of the vertical force on the tank against the water's weight
(clone walls: force_y_tank); the largest density variation; the global volume error eps_V; the mass drift;
the wall time) and speed.png (the largest speed against time).
"""

import argparse
from pathlib import Path

import numpy as np

from psph.particles import Kind
from psph.studies import (
    CASES,
    SCHEME_SETS,
    command_line,
    last_snapshot,
    parse_args,
    plot_histories,
    positive_float,
    positive_int,
    run_scene,
    write_table,
)

TANKS = {"box": "hydrostatic_tank.toml", "trapezoid": "trapezoidal_tank.toml"}
DEEP = 0.3  # the pressure's error in the water's lowest 30% (y < DEEP H), by the floor, away from the surface


def pressure_error(out, depth=1.0):
    """(RMS, max, max below y = DEEP H) over the fluid of |p - rho0 g (H - y)| in rho0 g H (rho0 = g = 1) at
    the last snapshot."""
    fields, _ = last_snapshot(out)
    fluid = fields["kind"] == int(Kind.FLUID)
    y = fields["position"][fluid, 1]
    error = np.abs(fields["pressure"][fluid] - (depth - y))
    return float(np.sqrt(np.mean(error**2))), float(error.max()), float(error[y < DEEP * depth].max())


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/tank"))
    parser.add_argument("--ranks", type=positive_int, default=1)
    parser.add_argument("--t-end", type=positive_float, default=10.0, help="t sqrt(g/H)")
    parser.add_argument("--tanks", nargs="+", default=list(TANKS), choices=list(TANKS))
    parser.add_argument("--resolutions", type=positive_int, nargs="+", default=[20, 40], help="H/dx of the box")
    parser.add_argument("--trapezoid-resolutions", type=positive_int, nargs="+", default=[25, 50],
                        help="H/dx (seed 002)")
    parser.add_argument("--walls", nargs="+", default=["clone", "ghost"], choices=["clone", "ghost"])
    parser.add_argument("--schemes", nargs="+", default=["delta_ale"], choices=list(SCHEME_SETS))
    args = parse_args(parser)
    rows, histories = [], {}
    cases = [(tank, walls, scheme, n) for tank in args.tanks for walls in (args.walls if tank == "box" else ["clone"])
             for scheme in args.schemes for n in (args.resolutions if tank == "box" else args.trapezoid_resolutions)]
    for tank, walls, scheme, n in cases:
        name = (f"{walls}_h{n}" if tank == "box" else f"{tank}_h{n}") + ("" if scheme == "delta_ale" else f"_{scheme}")
        run = run_scene(CASES / TANKS[tank], args.out / name, ranks=args.ranks,
                        sets=[f"domain.dx={1.0 / n}", f"time.t_end={args.t_end}", "output.every=0",
                              "output.history_every=20", f"bodies.0.model={walls}", *SCHEME_SETS[scheme]])
        h = run.history
        t = np.array([r["time"] for r in h])
        speed = np.array([r["max_speed"] for r in h])
        mass = np.array([r["total_mass"] for r in h])
        late = t >= 0.5 * args.t_end
        weight = [r["force_y_tank"] / -r["total_mass"] - 1.0 for r, keep in zip(h, late) if keep] \
            if walls == "clone" else [np.nan]  # g = 1; ghost walls report no force
        rows.append([tank, walls, scheme, n, run.summary["n_particles"], speed[-1], speed[late].max(),
                     *pressure_error(run.out), float(np.max(np.abs(weight))),
                     max(r["max_density_variation"] for r in h),
                     h[-1]["volume_error"], float(np.abs(mass / mass[0] - 1.0).max()),
                     run.summary["wall_time_s"]])
        histories[(tank, walls, scheme, n)] = (t, speed)
        print(rows[-1], flush=True)
    curves = [(t, speed, f"{tank}, {walls} walls, {scheme}, H/dx = {n}",
               {"ls": "--" if walls == "ghost" else (":" if tank == "trapezoid" else "-")})
              for (tank, walls, scheme, n), (t, speed) in histories.items()]
    plot_histories(args.out / "speed.png", curves, "t sqrt(g/H)", "max |u| / sqrt(g H)",
                   "Water at rest in a tank: spurious velocity", logy=True)
    print(write_table(args.out / "spurious",
                      ["tank", "walls", "scheme", "H/dx", "particles", f"max speed at t = {args.t_end:g}",
                       f"max speed, t >= {0.5 * args.t_end:g}", "RMS p error", "max p error",
                       f"max p error, y < {DEEP:g} H",
                       f"weight on the tank, max error t >= {0.5 * args.t_end:g}",
                       "max density variation", "eps_V(t_end)", "max mass drift", "wall s"], rows,
                      title=f"Water at rest to t sqrt(g/H) = {args.t_end:g}: speeds in sqrt(g H), pressure errors "
                            "against rho0 g (H - y) in rho0 g H",
                      note="Command: " + command_line()))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
