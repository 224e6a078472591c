"""Moving square in a box (SPHERIC benchmark 6; thesis 000 section 10.1, fig. 10.3-10.5): drag coefficient
histories (pressure and viscous parts) to t = 5 and Linf(grad C) histories for the explicit shifting
(Neuhauser, P_S = 10) and IIPS with the NFTS and MLS-II field updates, with the CPU time of each relative to
the explicit run (the thesis reports +33% for NFTS and +54% for MLS-II at Delta/L = 0.0125, D/dx = 80 if
L = D).

    .venv/bin/python run_scripts/moving_square.py [--dx 0.05] [--t-end 5] [--ranks 1 2] [--methods ...]

Writes results/moving_square/{cost.md,csv} (wall time, its ratio to the explicit run on as many ranks,
mean drag, Linf(grad C), IIPS' share of the step time), histories.csv (drag and Linf(grad C) against time),
drag.png and grad_c.png.
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from psph.studies import (  # noqa: E402
    CASES,
    RunStopped,
    command_line,
    parse_args,
    positive_float,
    positive_int,
    run_scene,
    stop_message,
    tag,
    write_histories,
    write_table,
)

METHODS = {
    "explicit P_S=10": ["shifting.method=neuhauser", "shifting.neuhauser_ps=10", "iips.update=none"],
    "IIPS + NFTS": ["shifting.method=iips", "iips.update=nfts"],
    "IIPS + MLS-II": ["shifting.method=iips", "iips.update=mls2"],
}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/moving_square"))
    parser.add_argument("--dx", type=positive_float, default=0.05)
    parser.add_argument("--t-end", type=positive_float, default=5.0)
    parser.add_argument("--ranks", type=positive_int, nargs="+", default=[1])
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    args = parse_args(parser)
    table, runs = [], {}
    for ranks in args.ranks:
        for name in args.methods:
            sets = METHODS[name]
            try:
                run = run_scene(CASES / "moving_square.toml", args.out / f"{tag(name)}_dx{args.dx}_n{ranks}",
                                sets=[f"domain.dx={args.dx}", f"time.t_end={args.t_end}", "output.every=1.0",
                                      "output.history_every=10", *sets], ranks=ranks)
            except RunStopped as err:
                print(f"{name} on {ranks} rank(s): stopped: {stop_message(err)}", flush=True)
                table.append([name, ranks, "stopped", "-", "-", "-", "-", "-"])
                continue
            runs[(name, ranks)] = run
            rows = [r for r in run.history if r["time"] >= 2.0]
            cd = np.mean([r["cd_pressure"] + r["cd_viscous"] for r in rows]) if rows else float("nan")
            summary = run.summary
            table.append([name, ranks, summary["wall_time_s"], None, cd, max(r["Linf_grad_c"] for r in run.history),
                          summary["final"]["iips_failures"], summary["iips_time_s"] / summary["step_time_s"]])
            print(f"{name} on {ranks} rank(s): wall {run.summary['wall_time_s']:.1f} s, mean cd(t >= 2) = {cd:.3f}",
                  flush=True)
    for row in table:
        base = runs.get(("explicit P_S=10", row[1]))
        if base is not None and row[2] != "stopped":
            row[3] = row[2] / base.summary["wall_time_s"]
    print(write_table(args.out / "cost", ["method", "ranks", "wall s", "wall / explicit", "mean cd (t>=2)",
                                          "max Linf(grad C)", "IIPS stalls", "IIPS share of the step"], table,
                      title=f"Moving square, D/dx = {1 / args.dx:g}, t = {args.t_end}",
                      note="Command: " + command_line()))
    write_histories(args.out / "histories.csv", ["method", "ranks"], runs.items(),
                    ["cd_pressure", "cd_viscous", "Linf_grad_c"])
    fig, (ax_p, ax_v) = plt.subplots(1, 2, figsize=(11, 4))
    fig2, ax_g = plt.subplots(figsize=(6, 4))
    for (name, ranks), run in runs.items():
        if ranks != args.ranks[0]:
            continue
        t = [r["time"] for r in run.history]
        ax_p.plot(t, [r["cd_pressure"] for r in run.history], label=name)
        ax_v.plot(t, [r["cd_viscous"] for r in run.history], label=name)
        ax_g.semilogy(t, [r["Linf_grad_c"] for r in run.history], label=name)
    ax_p.set(xlabel="t U / D", ylabel="cd pressure", ylim=(-1, 6))
    ax_v.set(xlabel="t U / D", ylabel="cd viscous")
    ax_g.set(xlabel="t U / D", ylabel="h max|grad C|", title="thesis fig. 10.3")
    ax_p.legend()
    ax_g.legend()
    fig.tight_layout()
    fig.savefig(args.out / "drag.png", dpi=120)
    fig2.tight_layout()
    fig2.savefig(args.out / "grad_c.png", dpi=120)


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
