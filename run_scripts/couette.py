"""The start-up Couette flow against its analytic transient, by scheme, viscous operator and resolution.

    .venv/bin/python run_scripts/couette.py [--schemes delta_ale riemann_ale riemann_low]
        [--viscosities monaghan morris] [--resolutions 20 40] [--t-end 1]

Runs cases/couette.toml (plates H = 1 apart, clone walls, the top plate moving at U = 1 from t = 0,
Re = 10, delta+ shifting) with each scheme (riemann_low: the Riemann SPH-ALE scheme with Zhang et al.'s
low-dissipation pressure; README, "Walls in the Riemann scheme"), each viscous operator (monaghan: seed 001
eq. 11's pi_ij; morris: Morris et al. 1997) and at each H/dx. Writes, in --out (results/couette), runs.md
and .csv: the largest error of u_x over the fluid at t_end against the analytic transient
(psph.analytic.couette_startup, checked in tests/test_analytic.py), in U; its order against the previous
(coarser) H/dx; the largest |u_y| (a plane shear stays plane); the mass drift; the wall time; and where psph
stopped a run, the stop's reason. The scene's delta+ shifting runs in the Riemann scheme too: psph warns of
it with walls (README, "Walls in the Riemann scheme"), yet it holds this short, gentle flow.
"""

import argparse
from pathlib import Path

import numpy as np

from psph.analytic import couette_startup
from psph.particles import Kind
from psph.scene.load import load_scene
from psph.studies import (
    CASES,
    SCHEME_SETS,
    RunStopped,
    command_line,
    last_snapshot,
    parse_args,
    positive_float,
    positive_int,
    rate,
    run_scene,
    stop_message,
    write_table,
)

SCENE = CASES / "couette.toml"  # its lengths in H, velocities in U (the plate's)


def couette_errors(out, nu):
    """(largest |u_x - u_exact|, largest |u_y|) over the fluid at the last snapshot, in U."""
    fields, t = last_snapshot(out)
    fluid = fields["kind"] == int(Kind.FLUID)
    y, u = fields["position"][fluid, 1], fields["velocity"][fluid]
    return float(np.abs(u[:, 0] - couette_startup(y, t, U=1.0, H=1.0, nu=nu)).max()), float(np.abs(u[:, 1]).max())


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/couette"))
    parser.add_argument("--schemes", nargs="+", default=list(SCHEME_SETS), choices=list(SCHEME_SETS))
    parser.add_argument("--viscosities", nargs="+", default=["monaghan", "morris"], choices=["monaghan", "morris"])
    parser.add_argument("--resolutions", type=positive_int, nargs="+", default=[20, 40], help="H/dx")
    parser.add_argument("--t-end", type=positive_float, default=1.0, help="t U / H")
    args = parse_args(parser)
    scene = load_scene(SCENE)
    nu = scene.physics.kinematic_viscosity(scene.domain)
    width = scene.domain.upper[0] - scene.domain.lower[0]
    for n in args.resolutions:
        if not float(n * width).is_integer():
            parser.error(f"argument --resolutions: H/dx = {n} does not fit the periodic width {width:g} H "
                         "(give an even H/dx)")
    rows = []
    for scheme in args.schemes:
        for viscosity in args.viscosities:
            previous = None
            for n in sorted(args.resolutions):
                try:
                    run = run_scene(SCENE, args.out / f"{scheme}_{viscosity}_h{n}",
                                    sets=[f"domain.dx={1.0 / n}", f"time.t_end={args.t_end}", "output.every=0",
                                          f"physics.viscosity={viscosity}", *SCHEME_SETS[scheme]])
                except RunStopped as err:  # diagnosed: its state and history are written
                    rows.append([scheme, viscosity, n, *[np.nan] * 5, stop_message(err).removeprefix("psph: error: ")])
                    previous = None
                    continue
                error, cross = couette_errors(run.out, nu)
                mass = np.array([r["total_mass"] for r in run.history])
                order = rate(previous[1], error, n / previous[0]) if previous else np.nan
                rows.append([scheme, viscosity, n, error, order, cross, float(np.abs(mass / mass[0] - 1.0).max()),
                             run.summary["wall_time_s"], "-"])
                previous = (n, error)
                print(rows[-1], flush=True)
    print(write_table(args.out / "runs", ["scheme", "viscosity", "H/dx", "max abs(u_x - u_exact)",
                                          "order against the previous H/dx", "max abs(u_y)", "max mass drift",
                                          "wall s", "stop"], rows, labels=3,
                      title=f"Start-up Couette flow at t U / H = {args.t_end:g} (Re = 10, clone walls, delta+): "
                            "errors in U",
                      note="Command: " + command_line()))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
