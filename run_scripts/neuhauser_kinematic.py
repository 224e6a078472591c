"""Neuhauser's shifting with the analytic Taylor-Green field imposed throughout (thesis 000 section 7.1-7.2.1):
the speed of sound at P_S = 1 (fig. 7.1: c0 = 10, 20, 100) and the particle-shifting coefficient at c0 = 10
(fig. 7.4: P_S = 1, 2, 5, 10, 20), by their Linf and L2(grad C) histories.

    .venv/bin/python run_scripts/neuhauser_kinematic.py [--dx 0.0125] [--t-end 0.2] [--ranks 1]
        [--out results/neuhauser_kinematic]

The thesis' runs are ALE-SPH runs whose fluid fields are held at the initial analytic solution; psph's are
kinematic runs (cases/kinematic_tgv.toml) whose particles move with the transport velocity u + du, u the
frozen field of thesis eq. 8.33 and du Neuhauser's law (eq. 6.33-6.35 with P_S, eq. 7.1), from the Cartesian
lattice (no pre-procedure), U = 1, dt = 0.2 dx / c0, the volumes held at dx^2. A run without shifting is the
reference. The thesis plots these at dx = 0.00625 (--dx 0.00625: 4 times the particles and twice the steps).
Writes table.md/csv and histories.png in --out.
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from psph.studies import CASES, fmt, parse_args, positive_float, positive_int, run_scene, write_table  # noqa: E402

SCENE = CASES / "kinematic_tgv.toml"
RUNS = {  # label: (figure, c0, P_S; None: no shifting)
    "no shifting": ("both", 10.0, None),
    "P_S = 1, c0 = 10": ("both", 10.0, 1.0),
    "P_S = 2": ("7.4", 10.0, 2.0),
    "P_S = 5": ("7.4", 10.0, 5.0),
    "P_S = 10": ("7.4", 10.0, 10.0),
    "P_S = 20": ("7.4", 10.0, 20.0),
    "c0 = 20": ("7.1", 20.0, 1.0),
    "c0 = 100": ("7.1", 100.0, 1.0),
}


def sets_for(label, dx, t_end):
    _, c0, ps = RUNS[label]
    sets = [f"domain.dx={dx}", f"time.t_end={t_end}", f"physics.sound_speed={c0}", "initial.sigma_over_dx=0",
            "iips.pre_newton=0", "iips.beta=0", "output.every=0", "output.history_every=10"]
    if ps is None:
        return sets + ["shifting.method=none"]
    return sets + ["shifting.method=neuhauser", f"shifting.neuhauser_ps={ps}"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/neuhauser_kinematic"))
    parser.add_argument("--ranks", type=positive_int, default=1)
    parser.add_argument("--dx", type=positive_float, default=0.0125)
    parser.add_argument("--t-end", type=positive_float, default=0.2)
    args = parse_args(parser)
    runs = {}
    for label in RUNS:
        tag = label.replace(" ", "").replace(",", "_").replace("=", "")
        runs[label] = run_scene(SCENE, args.out / tag, sets=sets_for(label, args.dx, args.t_end), ranks=args.ranks)
        s = runs[label].summary
        print(f"{label:18s} Linf(grad C) {s['final']['Linf_grad_c']:.4e} at t = {s['final']['time']:.4g}, "
              f"{s['steps']} steps, {s['step_time_s']:.1f} s", flush=True)

    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for col, figure in enumerate(("7.1", "7.4")):
        for label, run in runs.items():
            if RUNS[label][0] not in (figure, "both"):
                continue
            h = run.history
            for row, key in enumerate(("Linf_grad_c", "L2_grad_c")):
                axes[row, col].semilogy([r["time"] for r in h], [r[key] for r in h], label=label)
        axes[0, col].set(title=f"thesis fig. {figure}", ylabel="Linf(grad C)", ylim=(1e-4, None))
        axes[1, col].set(xlabel="t", ylabel="L2(grad C)", ylim=(1e-5, None))  # (from the lattice's round-off)
        axes[0, col].legend(fontsize=8)
    fig.suptitle(f"kinematic Taylor-Green with Neuhauser's shifting, dx = {args.dx}")
    fig.tight_layout()
    fig.savefig(args.out / "histories.png", dpi=120)

    base = runs["no shifting"].summary["step_time_s"]
    rows = []
    for label, run in runs.items():
        h, s = run.history, run.summary
        rows.append([label, RUNS[label][0], fmt(h[-1]["Linf_grad_c"], ".4g"), fmt(h[-1]["L2_grad_c"], ".4g"),
                     fmt(max(r["Linf_grad_c"] for r in h), ".4g"), fmt(h[-1]["L2_dfdx"], ".4g"), s["steps"],
                     fmt(s["step_time_s"], ".1f"), fmt(s["step_time_s"] / base, ".2f")])
    print(write_table(args.out / "table", ["run", "thesis fig.", "Linf(grad C) last", "L2(grad C) last",
                                           "Linf(grad C) max", "L2(d f/dx) last", "steps", "step time [s]",
                                           "relative"], rows,
                      title=f"Neuhauser's shifting, analytic field imposed, dx = {args.dx}, t = {args.t_end} "
                            "(the last row of each history is the last step's start)",
                      note="relative: step time over the run without shifting at c0 = 10."))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
