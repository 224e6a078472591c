"""Walls in the Riemann SPH-ALE scheme against delta-ALE-SPH: which shifting runs, how the volumes drift.

    .venv/bin/python run_scripts/riemann_walls.py [--flows cavity dam_break moving_square]
        [--schemes delta_ale riemann_ale riemann_low]
        [--shiftings none delta_plus neuhauser_pf iips iips_nfts | lind skillen oger neuhauser iips_mls2]
        [--cavity-dx 0.04] [--cavity-t-end 5]
        [--dam-dx 0.05] [--dam-t-end 3] [--square-dx 0.1] [--square-t-end 2] [--no-run]

Runs the lid-driven cavity (cases/lid_driven_cavity.toml, Re = 100, clone walls, the lid at U = 1), the
dam break (cases/dam_break.toml, its free-slip tank; diffusion switch off in the Riemann scheme, whose fluxes
have no diffusive terms) and the moving square (cases/moving_square.toml, SPHERIC 6's square towed through a
closed tank, Re = 100) in each scheme (riemann_low: the Riemann scheme with Zhang et al.'s low-dissipation
pressure) with each shifting: none; delta_plus; neuhauser_pf (Neuhauser's law with the fictitious pressure
P^F of thesis eq. 7.3-7.4, which ties the shift to the volume); iips (IIPS, fields not updated); iips_nfts
(IIPS with the NFTS update, thesis ch. 9); and on request the other explicit laws (lind, skillen, oger),
neuhauser (its constant P_S) and iips_mls2 (IIPS with the second-order MLS update). Writes, in --out
(results/riemann_walls), runs.md and .csv: the time each run reached (and the stop's reason where psph
stopped it), the largest |V/V0 - 1| and |rho/rho0 - 1| over the history's rows (every 10 steps: a stop's
own value is in its message; history.csv's max_volume_variation and max_density_variation), the mean and
the least V/V0 of the fluid within dx of a wall at the end (the box's sides; the moving square's sides), the
mass drift, and for the dam break the surge front at t = 1 and 2 (in H; Ritter's dry-bed bound is 2 + 2 t)
and the time it reaches the right wall.
--no-run makes the table from the runs already in --out.

The Riemann scheme's volumes follow the transport velocity and its mass the fluxes: a particle moved towards
a wall shrinks and gives its mass to its neighbours without a density change, so nothing pushes it back,
and a law built on the concentration (C = sum_j W_ij V_j) moves more particles into the smaller ones'
place. psph stops such a run when a volume has drifted by physics.max_volume_variation (README, "Walls in
the Riemann scheme").
"""

import argparse
import re
from pathlib import Path

import numpy as np

from psph.particles import Kind
from psph.scene.load import load_scene
from psph.studies import (
    CASES,
    SCHEME_SETS,
    NotRun,
    RunStopped,
    command_line,
    last_snapshot,
    parse_args,
    positive_float,
    run_scene,
    stop_message,
    write_table,
)

FLOWS = {"cavity": "lid_driven_cavity.toml", "dam_break": "dam_break.toml", "moving_square": "moving_square.toml"}
SHIFTINGS = {
    "none": ["shifting.method=none", "iips.update=none"],
    "delta_plus": ["shifting.method=delta_plus", "iips.update=none"],
    "neuhauser_pf": ["shifting.method=neuhauser", "shifting.fictitious_pressure=true", "iips.update=none"],
    "iips": ["shifting.method=iips", "iips.update=none"],
    "iips_nfts": ["shifting.method=iips", "iips.update=nfts"],
}
# run on request only (--shiftings): the other explicit laws, Neuhauser's with its constant P_S, IIPS + MLS2
EXTRA_SHIFTINGS = {
    **{law: [f"shifting.method={law}", "iips.update=none"] for law in ("lind", "skillen", "oger", "neuhauser")},
    "iips_mls2": ["shifting.method=iips", "iips.update=mls2"],
}
# per flow; the dam break's diffusion switch belongs to delta-ALE (the Riemann fluxes have no diffusive terms)
SCHEMES = {scheme: {flow: [*sets, *(["free_surface.lambda_diffusion=0"] if sets and flow == "dam_break" else [])]
                    for flow in FLOWS} for scheme, sets in SCHEME_SETS.items()}
RIGHT_WALL = 5.367  # cases/dam_break.toml: the tank's length (H = 1)


def near_wall_volumes(out, box, dx):
    """(mean, least) V/V0 of the fluid within dx of a wall at the last snapshot: of the sides of box (lower,
    upper corners), or with box None of the immersed body (its particles' nearest within 1.5 dx: the first
    layer lies dx/2 inside)."""
    fields, _ = last_snapshot(out)
    fluid = fields["kind"] == int(Kind.FLUID)
    pos = fields["position"][fluid]
    if box is None:
        from scipy.spatial import cKDTree

        gap = cKDTree(fields["position"][fields["kind"] == int(Kind.BODY)]).query(pos)[0] - 0.5 * dx
    else:
        gap = np.minimum(pos - box[0], box[1] - pos).min(axis=1)
    ratio = (fields["volume"][fluid] / fields["volume0"][fluid])[gap < dx]
    return (float(ratio.mean()), float(ratio.min())) if ratio.size else (np.nan, np.nan)


def front(history, t):
    """The surge front (history.csv's front_x) at the row nearest t, NaN if the run ended before."""
    rows = [r for r in history if abs(r["time"] - t) < 0.05]
    return min(rows, key=lambda r: abs(r["time"] - t))["front_x"] if rows else np.nan


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/riemann_walls"))
    parser.add_argument("--flows", nargs="+", default=list(FLOWS), choices=list(FLOWS))
    parser.add_argument("--schemes", nargs="+", default=list(SCHEMES), choices=list(SCHEMES),
                        help="riemann_low: riemann_ale with physics.riemann_dissipation = low")
    parser.add_argument("--shiftings", nargs="+", default=list(SHIFTINGS),
                        choices=[*SHIFTINGS, *EXTRA_SHIFTINGS], help="(default: %(default)s)")
    parser.add_argument("--cavity-dx", type=positive_float, default=0.04, help="L = 1")
    parser.add_argument("--cavity-t-end", type=positive_float, default=5.0, help="t U / L")
    parser.add_argument("--dam-dx", type=positive_float, default=0.05, help="H = 1")
    parser.add_argument("--dam-t-end", type=positive_float, default=3.0, help="t sqrt(g / H)")
    parser.add_argument("--square-dx", type=positive_float, default=0.1, help="the square's side = 1")
    parser.add_argument("--square-t-end", type=positive_float, default=2.0, help="t U / L")
    parser.add_argument("--no-run", action="store_true", help="the table from the finished runs only")
    args = parse_args(parser)
    resolution = {"cavity": (args.cavity_dx, args.cavity_t_end), "dam_break": (args.dam_dx, args.dam_t_end),
                  "moving_square": (args.square_dx, args.square_t_end)}
    rows = []
    for flow in args.flows:
        dx, t_end = resolution[flow]
        sets_flow = [f"domain.dx={dx}", f"time.t_end={t_end}", "output.every=0", "output.history_every=10"]
        box = load_scene(CASES / FLOWS[flow]).bodies[0]
        box = None if flow == "moving_square" else (np.subtract(box.center, 0.5 * np.asarray(box.size)),
                                                    np.add(box.center, 0.5 * np.asarray(box.size)))
        for scheme in args.schemes:
            for shifting in args.shiftings:
                out = args.out / f"{flow}_{scheme}_{shifting}"
                sets = [*sets_flow, *SCHEMES[scheme][flow], *(SHIFTINGS | EXTRA_SHIFTINGS)[shifting]]
                try:
                    run = run_scene(CASES / FLOWS[flow], out, sets=sets, only_finished=args.no_run)
                    history, reached, stop = run.history, t_end, ""
                except NotRun:
                    print(f"{out}: not run", flush=True)
                    continue
                except RunStopped as err:  # a diagnosed stop: its history and its state are written
                    from psph.io.history import read_history

                    stop = stop_message(err).removeprefix("psph: error: ")
                    history = read_history(out / "history.csv")
                    found = re.search(r"\bt = ([-+0-9.e]+)[,\]]", stop)
                    reached = float(found.group(1)) if found else history[-1]["time"]
                mass = np.array([r["total_mass"] for r in history])
                mean_v, least_v = near_wall_volumes(out, box, dx)
                hit = next((r["time"] for r in history if r.get("front_x", 0.0) > RIGHT_WALL - dx), np.nan)
                rows.append([flow, scheme, shifting, reached, max(r["max_volume_variation"] for r in history),
                             max(r["max_density_variation"] for r in history),
                             mean_v, least_v, float(np.abs(mass / mass[0] - 1.0).max()),
                             *((front(history, 1.0), front(history, 2.0), hit) if flow == "dam_break" else
                               (np.nan,) * 3), stop or "-"])
                print(rows[-1], flush=True)
    print(write_table(args.out / "runs",
                      ["flow", "scheme", "shifting", "t reached", "max abs(V/V0 - 1)", "max abs(rho/rho0 - 1)",
                       "near-wall mean V/V0", "near-wall least V/V0", "max mass drift", "front at t = 1",
                       "front at t = 2", "front at the wall", "stop"], rows, labels=3,
                      title="Walls in the Riemann scheme: " + ", ".join(
                          f"the {flow.replace('_', ' ')} at dx = {resolution[flow][0]:g} to "
                          f"t = {resolution[flow][1]:g}" for flow in args.flows)
                          + " (near-wall: the fluid within dx of the box's sides, or of the moving square, at the "
                          "end; the dam break's dx, front and times in H and sqrt(H / g))",
                      note="Command: " + command_line()))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
