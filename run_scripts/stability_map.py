"""Stability at the extremes: short Taylor-Green runs over perturbation, h/dx, c0/U, Re and shifting method,
each classified as ran (t_end reached, finite fields), stopped by a diagnosis (psph's one-line error, exit 3,
state saved) or blew up undiagnosed (NaN in the output of a finished run, a traceback, any other exit).

    .venv/bin/python run_scripts/stability_map.py [--t-end 0.5] [--dx 0.05] [--out results/stability_map]
        [--sigmas 0 0.5] [--ratios 1.2 2.0 2.5] [--c0 5 50] [--reynolds 10 10000]
        [--methods none delta_plus iips] [--set KEY=VALUE ...] [PETSc options]

Writes map.md (one row per case: outcome, the stopping message or L2|v_x - v_xA| at t_end) and map.png,
and exits 1 if any case blew up undiagnosed. Bi-periodic unit box, U = 1, delta-ALE-SPH, C6, RK3.
"""

import argparse
import itertools
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from psph.scene.schema import SHIFTING_METHODS  # noqa: E402
from psph.studies import (  # noqa: E402
    CASES,
    RunFailed,
    RunStopped,
    UsageError,
    last_snapshot,
    parse_args,
    positive_float,
    run_scene,
    smoothing_ratio,
    stop_message,
    write_table,
)

SCENE = CASES / "taylor_green.toml"
OUTCOMES = {"ran": "tab:green", "stopped (diagnosed)": "tab:orange", "BLEW UP (undiagnosed)": "tab:red"}


def run_case(out, sigma, ratio, c0, reynolds, method, dx, t_end):
    sets = [f"domain.dx={dx}", f"domain.h_over_dx={ratio}", f"initial.sigma_over_dx={sigma}",
            f"physics.sound_speed={c0}", f"physics.reynolds={reynolds}", f"shifting.method={method}",
            f"time.t_end={t_end}", "output.every=0", "output.history_every=20"]
    if method == "iips":
        sets += ["iips.update=nfts", "iips.threshold=0.001"]
    else:
        sets += ["iips.update=none"]
    try:
        run = run_scene(SCENE, out, sets)
    except RunStopped as err:  # psph's one-line diagnosis, with the state saved
        line = stop_message(err)
        if line.startswith("psph: error:") and list(out.glob("snapshot_*.h5")):
            return "stopped (diagnosed)", line.removeprefix("psph: error: ")
        return "BLEW UP (undiagnosed)", f"exit 3 without a saved state: {line}"
    except RunFailed as err:
        if err.returncode == 2:  # the scene or the command line is wrong: no outcome of the case, stop the map
            raise
        return "BLEW UP (undiagnosed)", f"exit {err.returncode}: {err}"
    data, _ = last_snapshot(out)
    if not all(np.isfinite(v).all() for v in data.values() if v.dtype.kind == "f"):
        return "BLEW UP (undiagnosed)", "non-finite fields in the final snapshot"
    return "ran", f"L2|v_x - v_xA| = {run.summary['final']['L2_vx_error']:.3g}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/stability_map"))
    parser.add_argument("--dx", type=positive_float, default=0.05)
    parser.add_argument("--t-end", type=positive_float, default=0.5)
    parser.add_argument("--sigmas", type=float, nargs="+", default=[0.0, 0.5])
    parser.add_argument("--ratios", type=smoothing_ratio, nargs="+", default=[1.2, 2.0, 2.5])
    parser.add_argument("--c0", type=positive_float, nargs="+", default=[5.0, 50.0])
    parser.add_argument("--reynolds", type=positive_float, nargs="+", default=[10.0, 1e4])
    parser.add_argument("--methods", nargs="+", default=["none", "delta_plus", "iips"], choices=SHIFTING_METHODS)
    args = parse_args(parser)
    rows = []
    cases = list(itertools.product(args.methods, args.sigmas, args.ratios, args.c0, args.reynolds))
    try:
        for k, (method, sigma, ratio, c0, reynolds) in enumerate(cases, 1):
            out = args.out / "runs" / f"{method}_s{sigma}_h{ratio}_c{c0:g}_Re{reynolds:g}"
            outcome, detail = run_case(out, sigma, ratio, c0, reynolds, method, args.dx, args.t_end)
            rows.append([method, sigma, ratio, c0, reynolds, outcome, detail])
            print(f"[{k}/{len(cases)}] {method:10s} sigma/dx={sigma} h/dx={ratio} c0/U={c0:g} Re={reynolds:g}: "
                  f"{outcome}; {detail}", flush=True)
    except UsageError:  # the study's own --set refused at the case that sets its key: no map of this command
        rows.clear()  # (a review: a finished map was replaced by the one case run before it)
        raise
    finally:  # the cases done so far, also when a refused one stops the map (none: the old map is kept)
        counts = {o: sum(r[5] == o for r in rows) for o in OUTCOMES}
        given = "".join(f", then --set {s}" for s in args.set) + (f", {' '.join(args.petsc)}" if args.petsc else "")
        note = f"dx = {args.dx}, t_end = {args.t_end}{given}; " + ", ".join(f"{o}: {n}" for o, n in counts.items())
        if rows:
            print(write_table(args.out / "map.md", ["method", "sigma/dx", "h/dx", "c0/U", "Re", "outcome",
                                                    "detail"], rows,
                              title="Stability map: Taylor-Green runs at the extremes", note=note, labels=5))
    # one panel per method: x = (h/dx, sigma/dx), y = (c0/U, Re), colour = outcome
    fig, axes = plt.subplots(1, len(args.methods), figsize=(5 * len(args.methods), 4.2), squeeze=False)
    xs = list(itertools.product(args.ratios, args.sigmas))
    ys = list(itertools.product(args.c0, args.reynolds))
    for ax, method in zip(axes.flat, args.methods):
        for r in rows:
            if r[0] != method:
                continue
            i, j = xs.index((r[2], r[1])), ys.index((r[3], r[4]))
            ax.add_patch(plt.Rectangle((i, j), 0.95, 0.95, color=OUTCOMES[r[5]]))
        ax.set_xlim(0, len(xs))
        ax.set_ylim(0, len(ys))
        ax.set_xticks([i + 0.5 for i in range(len(xs))], [f"h/dx {a:g}\nσ {b:g}" for a, b in xs], fontsize=7)
        ax.set_yticks([j + 0.5 for j in range(len(ys))], [f"c0/U {a:g}\nRe {b:g}" for a, b in ys], fontsize=7)
        ax.set_title(f"shifting: {method}")
    handles = [plt.Rectangle((0, 0), 1, 1, color=c) for c in OUTCOMES.values()]
    fig.legend(handles, list(OUTCOMES), loc="lower center", ncol=3)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(args.out / "map.png", dpi=110)
    return 1 if counts["BLEW UP (undiagnosed)"] else 0


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
