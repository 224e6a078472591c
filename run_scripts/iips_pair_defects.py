"""Why IIPS Procedure B diverges in the Taylor-Green run at h/dx = 3, dx = 0.0125: the printed operator
(thesis eq. 8.32) on the particles just before the run stops, against the square lattice.

    .venv/bin/python run_scripts/iips_pair_defects.py [--dx 0.0125] [--h-over-dx 3] [--t-end 0.2]
        [--every 0.005] [--ranks 2]

Runs cases/taylor_green.toml with IIPS (Procedure B, no field update) until it stops or reaches --t-end.
For the square lattice, the last regular snapshot before the stop and the state psph saved at the
diagnosis (after the diverging Newton iteration), psph.studies.iips_pair_defects reports the smallest
spacing, |Hess C_i| relative to the operator's self term (the part of the exact Jacobian the printed
operator leaves out), its correlation with the distance to the nearest particle, and three Newton
iterations with the printed operator solved exactly (LU), so that BCGS plays no part.
Writes results/iips_pair_defects/defects.md.
"""

import argparse
from pathlib import Path

import numpy as np

from psph.studies import (
    RunStopped,
    command_line,
    fmt,
    iips_pair_defects,
    last_snapshot,
    parse_args,
    positive_float,
    positive_int,
    run_scene,
    smoothing_ratio,
    stop_message,
    write_table,
)

ROOT = Path(__file__).resolve().parents[1]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dx", type=positive_float, default=0.0125)
    parser.add_argument("--h-over-dx", type=smoothing_ratio, default=3.0)
    parser.add_argument("--t-end", type=positive_float, default=0.2)
    parser.add_argument("--every", type=positive_float, default=0.005, help="snapshot interval")
    parser.add_argument("--ranks", type=positive_int, default=2)
    parser.add_argument("--out", type=Path, default=Path("results/iips_pair_defects"))
    args = parse_args(parser)
    run_dir = args.out / "run"
    sets = [f"domain.dx={args.dx}", f"domain.h_over_dx={args.h_over_dx}", "iips.update=none",
            f"time.t_end={args.t_end}", f"output.every={args.every}"]
    try:
        run_scene(ROOT / "cases/taylor_green.toml", run_dir, sets, ranks=args.ranks)
        stop, states = "reached t_end", [(-1, "")]
    except RunStopped as err:
        stop = "stopped: " + stop_message(err)
        states = [(-2, ", before the stop"), (-1, ", saved at the stop")]
    print(stop, flush=True)
    m = round(1.0 / args.dx)
    g = (np.arange(m) + 0.5) / m
    cases = [(f"square lattice {m} x {m}", np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2),
              np.full(m * m, 1.0 / m**2))]
    for index, label in states:
        fields, t = last_snapshot(run_dir, index)
        cases.append((f"Taylor-Green run, t = {t:.4g}{label}", fields["position"], fields["volume"]))
    rows = []
    for label, pos, vol in cases:
        r = iips_pair_defects(pos, vol, args.h_over_dx)
        ratio, nearest = r["hess_c_ratio"], r["nearest"]
        corr = np.corrcoef(ratio, nearest)[0, 1] if nearest.std() > 1e-12 else float("nan")
        row = [label, f"{r['min_spacing']:.3f}", f"{100 * np.median(ratio):.2f}%", f"{100 * ratio.max():.2f}%",
               "-" if np.isnan(corr) else f"{corr:.2f}", " / ".join(fmt(v) for v in r["linf"]),
               " / ".join(f"{v:.3f}" for v in r["max_step"])]
        rows.append(row)
        print(" | ".join(row), flush=True)
    write_table(args.out / "defects",
                ["distribution", "min spacing / dx", "median |Hess C_i| / self", "max |Hess C_i| / self",
                 "corr(ratio, nearest distance)", "h Linf(grad C), Newton 0-3", "max step / dx, Newton 1-3"],
                rows, title=f"IIPS printed operator at h/dx = {args.h_over_dx:g}, dx = {args.dx:g}",
                note=f"Run: cases/taylor_green.toml --set {' --set '.join(sets)} ({stop}). Newton iterations "
                     "with the printed operator solved by LU. Command: " + command_line())


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
