"""The start-up Couette flow against its analytic transient, by scheme, viscous operator and resolution.

    .venv/bin/python run_scripts/couette.py [--schemes delta_ale riemann_ale riemann_low]
        [--viscosities monaghan morris] [--resolutions 20 40] [--t-end 1]

Runs cases/couette.toml (plates H = 1 apart, clone walls, the top plate moving at U = 1 from t = 0,
Re = 10, delta+ shifting) with each scheme (riemann_low: the Riemann SPH-ALE scheme with Zhang et al.'s
low-dissipation pressure; README, "Walls in the Riemann scheme"), each viscous operator (monaghan: seed 001
eq. 11's pi_ij; morris: Morris et al. 1997) and at each H/dx. Writes, in --out (results/couette), runs.md
and .csv: the largest error of u_x over the fluid at t_end against the analytic transient
(psph.analytic.couette_startup, checked in tests/test_analytic.py), in U; its order between successive
resolutions; the largest |u_y| (a plane shear stays plane); the wall time.
"""

import argparse
from pathlib import Path

import numpy as np

from psph.analytic import couette_startup
from psph.particles import Kind
from psph.studies import (
    CASES,
    command_line,
    last_snapshot,
    parse_args,
    positive_float,
    positive_int,
    rate,
    run_scene,
    write_table,
)

SCHEMES = {"delta_ale": [], "riemann_ale": ["physics.scheme=riemann_ale"],
           "riemann_low": ["physics.scheme=riemann_ale", "physics.riemann_dissipation=low"]}
NU = 0.1  # cases/couette.toml: U H / Re


def couette_errors(out):
    """(largest |u_x - u_exact|, largest |u_y|) over the fluid at the last snapshot, in U."""
    fields, t = last_snapshot(out)
    fluid = fields["kind"] == int(Kind.FLUID)
    y, u = fields["position"][fluid, 1], fields["velocity"][fluid]
    return float(np.abs(u[:, 0] - couette_startup(y, t, U=1.0, H=1.0, nu=NU)).max()), float(np.abs(u[:, 1]).max())


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/couette"))
    parser.add_argument("--schemes", nargs="+", default=list(SCHEMES), choices=list(SCHEMES))
    parser.add_argument("--viscosities", nargs="+", default=["monaghan", "morris"], choices=["monaghan", "morris"])
    parser.add_argument("--resolutions", type=positive_int, nargs="+", default=[20, 40], help="H/dx")
    parser.add_argument("--t-end", type=positive_float, default=1.0, help="t U / H")
    args = parse_args(parser)
    rows = []
    for scheme in args.schemes:
        for viscosity in args.viscosities:
            previous = None
            for n in sorted(args.resolutions):
                run = run_scene(CASES / "couette.toml", args.out / f"{scheme}_{viscosity}_h{n}",
                                sets=[f"domain.dx={1.0 / n}", f"time.t_end={args.t_end}", "output.every=0",
                                      f"physics.viscosity={viscosity}", *SCHEMES[scheme]])
                error, cross = couette_errors(run.out)
                order = rate(previous[1], error, n / previous[0]) if previous else np.nan
                rows.append([scheme, viscosity, n, error, order, cross, run.summary["wall_time_s"]])
                previous = (n, error)
                print(rows[-1], flush=True)
    print(write_table(args.out / "runs", ["scheme", "viscosity", "H/dx", "max abs(u_x - u_exact)", "order",
                                          "max abs(u_y)", "wall s"], rows, labels=3,
                      title=f"Start-up Couette flow at t U / H = {args.t_end:g} (Re = 10, clone walls, delta+): "
                            "errors in U",
                      note="Command: " + command_line()))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
