"""Taylor-Green vortex at Re = 100 (thesis 000 Tables 7.1 and 9.1): L2|v_x - v_xA| and the kinetic-energy
error at t = 1 for each shifting method and resolution, the convergence rates, and the wall time against
the error (the Pareto front a user needs to choose a method), with the IIPS overhead relative to the step.

    .venv/bin/python run_scripts/tgv_tradeoff.py [--ranks 2] [--resolutions 0.05 0.025 0.0125 0.00625]
                                                 [--methods ...] [--procedure A] [--set KEY=VALUE] [--no-run]

Writes results/tgv_tradeoff/{convergence,tradeoff}.{md,csv} and tradeoff.png. Scheme: delta-ALE-SPH (seed
001; --set physics.scheme=riemann_ale for the thesis' own Riemann SPH-ALE), Wendland C6, h/dx = 2, c0 = 10,
RK3, CFL 0.2 (thesis eq. 5.52); IIPS Procedure B with Linf(grad C) <= 0.001 (thesis ch. 9); --procedure A:
at least one Newton iteration every step.
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from psph.studies import (  # noqa: E402
    CASES,
    NotRun,
    RunStopped,
    pareto,
    parse_args,
    positive_float,
    positive_int,
    rate,
    run_scene,
    stop_message,
    tag,
    write_table,
)  # noqa: E402

METHODS = {  # label: scene overrides
    "no shifting": ["shifting.method=none", "iips.update=none"],
    "delta+": ["shifting.method=delta_plus", "iips.update=none"],
    # eq. 6.33 as Neuhauser (2014) wrote it: the first column of Tables 7.1 and 9.1
    # (P^F off said outright: a --set of it is then refused, not tabled as P_S's row, studies.study_command)
    "Neuhauser P_S=1": ["shifting.method=neuhauser", "shifting.neuhauser_ps=1", "shifting.fictitious_pressure=false",
                        "iips.update=none"],
    "Neuhauser P_S=10": ["shifting.method=neuhauser", "shifting.neuhauser_ps=10",  # eq. 7.1
                         "shifting.fictitious_pressure=false", "iips.update=none"],
    "Neuhauser P^F": ["shifting.method=neuhauser", "shifting.fictitious_pressure=true", "iips.update=none"],  # 7.4
    "IIPS": ["shifting.method=iips", "iips.update=none"],
    "IIPS + NFTS": ["shifting.method=iips", "iips.update=nfts"],
    "IIPS + MLS-II": ["shifting.method=iips", "iips.update=mls2"],
    "IIPS + MLS-II increment": ["shifting.method=iips", "iips.update=mls2_increment"],
}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/tgv_tradeoff"))
    parser.add_argument("--ranks", type=positive_int, default=1)
    parser.add_argument("--t-end", type=positive_float, default=1.0)
    parser.add_argument("--resolutions", type=positive_float, nargs="+", default=[0.05, 0.025, 0.0125, 0.00625])
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--procedure", choices=["A", "B"],
                        help="IIPS procedure (thesis Algorithms 2-3; default: the scene's, B)")
    parser.add_argument("--no-run", action="store_true",
                        help="run nothing: tabulate the finished runs in --out ('-' for the others)")
    args = parse_args(parser)
    runs, stops = {}, {}
    for dx in args.resolutions:
        for label in args.methods:
            try:
                run = run_scene(CASES / "taylor_green.toml", args.out / f"{tag(label)}_dx{dx}", ranks=args.ranks,
                                sets=METHODS[label] + [f"domain.dx={dx}", f"time.t_end={args.t_end}",
                                                       "output.every=0", "output.history_every=50"]
                                + ([f"iips.procedure={args.procedure}"] if args.procedure else []),
                                only_finished=args.no_run)
            except NotRun:
                print(f"{label} dx={dx}: not run", flush=True)
                runs[(label, dx)] = None
                continue
            except RunStopped as exc:  # a run stopped by a diagnosis is a result too: its cell says so
                stops[(label, dx)] = "stopped: " + stop_message(exc).removeprefix("psph: error: ")
                print(f"{label} dx={dx}: {stops[(label, dx)]}", flush=True)
                runs[(label, dx)] = None
                continue
            runs[(label, dx)] = run
            f = run.summary["final"]
            print(f"{label:18s} dx={dx}: L2={f['L2_vx_error']:.4e} E_k err={f['kinetic_energy_error']:.3e} "
                  f"wall={run.summary['wall_time_s']:.1f}s", flush=True)

    def err(label, dx, key="L2_vx_error"):
        run = runs.get((label, dx))
        return run.summary["final"][key] if run else float("nan")

    def cell(label, dx, key="L2_vx_error"):  # the error, why a run has none ("stopped: ..."), or "-" (not run)
        return err(label, dx, key) if runs.get((label, dx)) else stops.get((label, dx))

    overrides = f" Scene overrides: {', '.join(args.set)}." if args.set else ""
    rows = []
    for label in args.methods:
        e = [err(label, dx) for dx in args.resolutions]
        row = [label]
        for k, dx in enumerate(args.resolutions):
            both = k and runs.get((label, args.resolutions[k - 1])) and runs.get((label, dx))
            row += [cell(label, dx), rate(e[k - 1], e[k], args.resolutions[k - 1] / dx) if both else None]
        row.append(cell(label, args.resolutions[-1], "kinetic_energy_error"))
        rows.append(row)
    header = ["method"]
    for dx in args.resolutions:
        header += [f"L2 dx={dx}", "rate"]
    header.append(f"E_k error dx={args.resolutions[-1]}")
    print(write_table(args.out / "convergence", header, rows,
                      title=f"Taylor-Green Re = 100: L2|v_x - v_xA| at t = {args.t_end} (thesis Table 9.1)",
                      note="rate = observed order between successive resolutions." + overrides))

    trade, fig = [], plt.figure(figsize=(6, 4.5))
    for label in args.methods:
        pts = [(runs[(label, dx)].summary["wall_time_s"], err(label, dx), dx) for dx in args.resolutions
               if runs.get((label, dx))]
        if pts:
            plt.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", label=label)
        for wall, e, dx in pts:
            s = runs[(label, dx)].summary
            overhead = s.get("iips_time_s", 0.0) / max(s["step_time_s"] - s.get("iips_time_s", 0.0), 1e-12)
            trade.append([label, dx, wall, e, s["steps"], overhead if label.startswith("IIPS") else "-"])
    if not trade:  # every run stopped: no time against error (the old figure and table are kept)
        print(f"no finished run: {args.out / 'tradeoff.md'} and tradeoff.png not written", flush=True)
        return
    front = set(pareto([(row[2], row[3]) for row in trade]))
    for i, row in enumerate(trade):
        row.append("*" if i in front else "")
    plt.xlabel("wall time [s]")
    plt.ylabel(f"L2|v_x - v_xA| at t = {args.t_end:g}")
    plt.legend(fontsize=7)
    plt.tight_layout()
    fig.savefig(args.out / "tradeoff.png", dpi=120)
    print(write_table(args.out / "tradeoff", ["method", "dx/L", "wall time [s]", "L2 error", "steps",
                                               "IIPS time / rest of the step", "Pareto"], trade,
                      title=f"Taylor-Green: cost against accuracy ({args.ranks} rank(s))",
                      note="IIPS overhead = time in IIPS and its field update over the remaining step time "
                           "(thesis: 10-70% for Procedure B)." + overrides))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
