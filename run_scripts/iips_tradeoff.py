"""The speed-accuracy trade of IIPS, measured: KSP rtol (1e-1, 1e-2, 1e-6) x preconditioner (jacobi,
hypre, gamg) on the static case, and threshold beta x h/dx on the kinematic case, each as accuracy
against wall time (the thesis found rtol 1e-1 not robust and 1e-2 the best compromise, section 8.3.1).

    .venv/bin/python run_scripts/iips_tradeoff.py [--ranks 1] [--out results/iips_tradeoff]

Static: dx/L = 0.0125 (6400 particles), sigma/dx = 0.1, 10 Newton iterations; accuracy = final L2(grad C)
and L2(d f/dx) relative to the Cartesian lattice (l = 0.5 L); monotonic = L2(grad C) never rose by more
than 10% from one iteration to the next within the first 5 iterations. Kinematic: dx/L = 0.025,
t = 0.1, Procedure B; accuracy = time-mean Linf(grad C) and final L2(d f/dx) (l = L).
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from psph.studies import CASES, run_scene, stop_message, write_table  # noqa: E402


def pareto(points):
    """Indices of the points no other point beats in both time and error."""
    return [i for i, (t, e) in enumerate(points)
            if not any(t2 <= t and e2 <= e and (t2, e2) != (t, e) for t2, e2 in points)]


def static_sweep(out, ranks):
    rows, points = [], []
    for pc in ("jacobi", "hypre", "gamg"):
        for rtol in (1e-1, 1e-2, 1e-6):
            try:
                run = run_scene(CASES / "static_perturbed.toml", out / f"static_{pc}_{rtol}", ranks=ranks,
                                sets=["domain.dx=0.0125", "initial.sigma_over_dx=0.1", "shifting.method=iips",
                                      "iips.max_newton=10"],
                                petsc=["-iips_pc_type", pc, "-iips_ksp_rtol", str(rtol)])
            except RuntimeError as exc:  # a diagnosed failure is a result of the sweep
                rows.append([pc, rtol, "failed: " + stop_message(exc)[:80]] + ["-"] * 5)
                print(rows[-1], flush=True)
                continue
            h = run.history
            l2 = [r["L2_grad_c"] for r in h]
            monotonic = all(b <= 1.1 * a for a, b in zip(l2[:6], l2[1:6]))
            t = run.summary["shifting_time_s"]
            err = h[-1]["L2_dfdx"] / h[-1]["L2_dfdx_cartesian"]
            rows.append([pc, rtol, t, run.summary["linear_iterations"], l2[5], l2[-1], err,
                         "yes" if monotonic else "no"])
            points.append((t, l2[-1]))
            print(rows[-1], flush=True)
    front = set(pareto(points))
    k = 0
    for row in rows:
        if isinstance(row[2], str):
            row.append("")
            continue
        row.append("*" if k in front else "")
        k += 1
    table = write_table(out / "static", ["PC", "KSP rtol", "shifting time [s]", "KSP iterations",
                                         "L2(grad C) it 5", "L2(grad C) it 10", "L2(df/dx)/Cartesian",
                                         "monotonic (it 0-5)", "Pareto"], rows,
                        title="Static case, 10 Newton iterations: solver settings against accuracy and time")
    return table, rows, points


def kinematic_sweep(out, ranks):
    rows, points = [], []
    for ratio in (2.0, 1.6):
        for beta in (5.0, 10.0, 20.0):
            run = run_scene(CASES / "kinematic_tgv.toml", out / f"kin_h{ratio}_b{beta}", ranks=ranks,
                            sets=["domain.dx=0.025", f"domain.h_over_dx={ratio}", "time.t_end=0.1",
                                  f"iips.beta={beta}", "iips.max_newton=50", "iips.on_failure=warn",
                                  "iips.on_stall=warn", "output.every=0"])
            s = run.summary
            linf = [r["Linf_grad_c"] for r in run.history[1:]]
            mean_linf = sum(linf) / len(linf)
            rows.append([ratio, beta, s["step_time_s"], s["newton_iterations"] / s["steps"], s["failed_calls"],
                         mean_linf, s["final"]["L2_dfdx"]])
            points.append((s["step_time_s"], s["final"]["L2_dfdx"]))
            print(rows[-1], flush=True)
    table = write_table(out / "kinematic", ["h/dx", "beta", "step time [s]", "Newton it. per step",
                                            "stalled calls", "mean Linf(grad C)", "final L2(df/dx)"], rows,
                        title="Kinematic case (dx = 0.025, t = 0.1, Procedure B): threshold and h/dx against cost")
    return table, rows, points


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/iips_tradeoff"))
    parser.add_argument("--ranks", type=int, default=1)
    args = parser.parse_args()
    run_scene(CASES / "static_perturbed.toml", args.out / "warmup", sets=["shifting.method=iips", "iips.max_newton=1"])
    static_table, static_rows, static_points = static_sweep(args.out, args.ranks)
    kin_table, kin_rows, kin_points = kinematic_sweep(args.out, args.ranks)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for row, (t, e) in zip([r for r in static_rows if not isinstance(r[2], str)], static_points):
        axes[0].loglog(t, e, "o" if row[0] == "jacobi" else ("s" if row[0] == "hypre" else "^"),
                       color={0.1: "C3", 0.01: "C0", 1e-6: "C2"}[row[1]])
        axes[0].annotate(f"{row[0]}, {row[1]:g}", (t, e), fontsize=7)
    axes[0].set(xlabel="shifting time [s]", ylabel="L2(grad C) after 10 iterations", title="static, dx = 0.0125")
    for row, (t, e) in zip(kin_rows, kin_points):
        axes[1].loglog(t, e, "o", color="C0" if row[0] == 2.0 else "C1")
        axes[1].annotate(f"h/dx={row[0]:g}, beta={row[1]:g}", (t, e), fontsize=7)
    axes[1].set(xlabel="time-loop wall time [s]", ylabel="final L2(d f/dx)", title="kinematic, dx = 0.025, t = 0.1")
    fig.tight_layout()
    fig.savefig(args.out / "tradeoff.png", dpi=120)
    print(static_table)
    print(kin_table)


if __name__ == "__main__":
    main()
