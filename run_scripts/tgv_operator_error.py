"""Why the Taylor-Green runs stop converging: the delta-ALE-SPH viscous operator (seed 001 eq. 11) and
pressure gradient applied to the analytic vortex on the particle distributions the runs left at t = 1,
and on the square lattice, at h/dx = 2 (the runs') and larger.

    .venv/bin/python run_scripts/tgv_operator_error.py [--runs results/tgv_tradeoff results/tgv_tradeoff_A ...]
                                                       [--h-over-dx 2 2.5 3] [--lattices 40 80 160]
                                                       [--viscosity monaghan|morris]

Reads every run directory under --runs (as run_scripts/tgv_tradeoff.py writes them) that reached t = 1
and writes results/tgv_operator_error/operators.{md,csv}. nu_eff / nu is the kinetic-energy-weighted
effective viscosity of the discrete operator (psph.studies.tgv_operator_errors); with it alone, E_k at
t = 1 would be off by exp(-16 pi^2 (nu_eff - nu) / (U L)) - 1 at Re = 100, the column set beside the
run's own E_k error.
"""

import argparse
import json
import math
from pathlib import Path

import numpy as np

from psph.errors import UsageError
from psph.studies import (
    check_memory,
    command_line,
    fmt,
    last_snapshot,
    parse_plain,
    positive_int,
    smoothing_ratio,
    tgv_operator_errors,
    unit_box_bytes,
    unit_box_kernel,
    write_table,
)


def implied_energy_error(ratio, reynolds=100.0, t=1.0):
    """E_k(t) relative error of a vortex decaying with nu_eff = ratio * nu instead of nu (thesis eq. 3.2)."""
    return math.exp(-16.0 * math.pi**2 * (ratio - 1.0) * t / reynolds) - 1.0


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, nargs="+",
                        default=[Path("results/" + name) for name in ("tgv_tradeoff", "tgv_tradeoff_A", "tgv_hdx3")])
    parser.add_argument("--h-over-dx", type=smoothing_ratio, nargs="+", default=[2.0, 2.5, 3.0])
    parser.add_argument("--lattices", type=positive_int, nargs="+", default=[40, 80, 160])
    parser.add_argument("--out", type=Path, default=Path("results/tgv_operator_error"))
    parser.add_argument("--viscosity", choices=("monaghan", "morris"), default="monaghan",
                        help="the viscous operator measured (physics.viscosity)")
    args = parse_plain(parser)
    missing = [str(p) for p in args.runs if not p.is_dir()]
    if missing:
        parser.error(f"--runs: no directory {', '.join(missing)}")
    for m in args.lattices:  # (the runs' distributions are checked as they are read: tgv_operator_errors)
        check_memory(parser, "--lattices", m, unit_box_bytes(m * m, max(args.h_over_dx)), m * m)
        for hdx in args.h_over_dx:
            try:
                unit_box_kernel(m * m, hdx)
            except UsageError as err:
                parser.error(f"argument --lattices / --h-over-dx: lattice {m} x {m}, {err}")
    cases = []
    for m in args.lattices:
        g = (np.arange(m) + 0.5) / m
        cases.append((f"square lattice {m} x {m}", 1.0 / m, None,
                      np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2), np.full(m * m, 1.0 / m**2)))
    for runs in args.runs:
        for run in sorted(p.parent for p in runs.glob("*/summary.json")):
            summary = json.loads((run / "summary.json").read_text())
            fields, t = last_snapshot(run)
            if abs(t - 1.0) > 1e-9:
                print(f"{run}: last snapshot at t = {t:g}, not 1: left out", flush=True)
                continue
            cases.append((f"{runs.name}/{run.name}", summary["scene"]["domain"]["dx"], summary["final"],
                          fields["position"], fields["volume"]))
    rows = []
    for label, dx, final, pos, vol in cases:
        row = [label, dx, fmt(final["L2_vx_error"]) if final else "-",
               f"{100 * final['kinetic_energy_error']:.1f}%" if final else "-"]
        for hdx in args.h_over_dx:
            e = tgv_operator_errors(pos, vol, hdx, morris=args.viscosity == "morris")
            row += [f"{e['nu_eff_ratio']:.4f}", fmt(e["viscous_rms"]), fmt(e["grad_p_rms"])]
            if hdx == args.h_over_dx[0]:
                row.append(f"{100 * implied_energy_error(e['nu_eff_ratio']):.1f}%")
        rows.append(row)
        print(" | ".join(map(str, row)), flush=True)
    header = ["distribution", "dx", "run: L2|v_x - v_xA|", "run: E_k error"]
    for hdx in args.h_over_dx:
        header += [f"nu_eff/nu h/dx={hdx:g}", f"visc. RMS err h/dx={hdx:g}", f"grad p RMS err h/dx={hdx:g}"]
        if hdx == args.h_over_dx[0]:
            header.append(f"E_k error implied by nu_eff, h/dx={hdx:g}")
    write_table(args.out / "operators", header, rows,
                title=f"Taylor-Green: the viscous operator ({args.viscosity}) and grad p on the runs' distributions "
                      "at t = 1",
                note="Analytic vortex at t = 0 applied to the positions and volumes of each run's last snapshot; "
                     "Wendland C6; RMS errors relative to the exact term. Command: " + command_line())


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
