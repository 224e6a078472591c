"""The speed-accuracy trade of IIPS, measured on the static and the kinematic case: KSP rtol (1e-1, 1e-2,
1e-6) x preconditioner (jacobi, matrix-free and assembled; hypre, gamg) at h/dx = 2 (kinematic:
beta = 10), h/dx (2, 1.6, 1.3) with the default solver (kinematic: x threshold beta 5, 10, 20), each as
accuracy against wall time (the thesis found rtol 1e-1 not robust and 1e-2 the best compromise, section
8.3.1).

    .venv/bin/python run_scripts/iips_tradeoff.py [--ranks 1] [--out results/iips_tradeoff] [--quick]

Static: dx/L = 0.0125 (6400 particles), sigma/dx = 0.1, 10 Newton iterations; accuracy = final L2(grad C)
and L2(d f/dx) relative to the Cartesian lattice (l = 0.5 L); monotonic = L2(grad C) never rose by more
than 10% from one iteration to the next within the first 5 iterations. Kinematic: dx/L = 0.025,
t = 0.1, Procedure B after the 100-iteration pre-procedure, threshold beta times its final Linf(grad C);
accuracy = time-mean Linf(grad C) and final L2(d f/dx) (l = L).

--quick is a smoke run (tests/test_run_scripts.py) of every kind of row at a fraction of the cost: static
dx/L = 0.05 (400 particles), kinematic dx/L = 0.1 to t = 0.02, the solvers jacobi 1e-2 (the default) and
jacobi_assembled 1e-1, h/dx 1.6 besides 2 in the static sweep, h/dx 2 and beta 10 only in the kinematic one.
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from psph.studies import CASES, RunStopped, pareto, parse_args, positive_int, run_scene, stop_message, write_table  # noqa: E402

# preconditioner: (-iips_pc_type, scene overrides). Jacobi runs matrix-free (iips.operator "auto"), and once
# more on the assembled matrix; hypre and GAMG need the assembled matrix ("auto" gives it them)
PCS = {"jacobi": ("jacobi", []), "jacobi_assembled": ("jacobi", ["iips.operator=assembled"]),
       "hypre": ("hypre", []), "gamg": ("gamg", [])}
SOLVERS = [(pc, rtol) for pc in PCS for rtol in (1e-1, 1e-2, 1e-6)]
DEFAULT_SOLVER = ("jacobi", 1e-2)
# the sweeps' settings: static dx, the static sweep's other h/dx, kinematic dx, t_end, h/dx and beta, the solvers
FULL = {"static_dx": 0.0125, "static_ratios": (1.6, 1.3), "kinematic_dx": 0.025, "t_end": 0.1,
        "kinematic_ratios": (2.0, 1.6, 1.3), "betas": (5.0, 10.0, 20.0), "solvers": SOLVERS}
QUICK = {"static_dx": 0.05, "static_ratios": (1.6,), "kinematic_dx": 0.1, "t_end": 0.02,
         "kinematic_ratios": (2.0,), "betas": (10.0,), "solvers": [DEFAULT_SOLVER, ("jacobi_assembled", 1e-1)]}


def static_sweep(out, ranks, sweep=FULL):
    rows, points = [], []
    cases = [(2.0, pc, rtol) for pc, rtol in sweep["solvers"]] + [(ratio, *DEFAULT_SOLVER)
                                                                   for ratio in sweep["static_ratios"]]
    for ratio, pc, rtol in cases:
        name = f"static_{pc}_{rtol}" + ("" if ratio == 2.0 else f"_h{ratio}")
        try:
            run = run_scene(CASES / "static_perturbed.toml", out / name, ranks=ranks,
                            sets=[f"domain.dx={sweep['static_dx']}", "initial.sigma_over_dx=0.1",
                                  "shifting.method=iips", "iips.max_newton=10", f"domain.h_over_dx={ratio}",
                                  *PCS[pc][1]],
                            petsc=["-iips_pc_type", PCS[pc][0], "-iips_ksp_rtol", str(rtol)])
        except RunStopped as exc:  # a diagnosed failure is a result of the sweep
            rows.append([ratio, pc, rtol, "failed: " + stop_message(exc)[:80]] + ["-"] * 5)
            print(rows[-1], flush=True)
            continue
        h = run.history
        l2 = [r["L2_grad_c"] for r in h]
        monotonic = all(b <= 1.1 * a for a, b in zip(l2[:6], l2[1:6]))
        t = run.summary["shifting_time_s"]
        err = h[-1]["L2_dfdx"] / h[-1]["L2_dfdx_cartesian"]
        rows.append([ratio, pc, rtol, t, run.summary["linear_iterations"], l2[5], l2[-1], err,
                     "yes" if monotonic else "no"])
        points.append((t, l2[-1]))
        print(rows[-1], flush=True)
    front = set(pareto(points))
    k = 0
    for row in rows:
        if isinstance(row[3], str):
            row.append("")
            continue
        row.append("*" if k in front else "")
        k += 1
    table = write_table(out / "static", ["h/dx", "PC", "KSP rtol", "shifting time [s]", "KSP iterations",
                                         "L2(grad C) it 5", "L2(grad C) it 10", "L2(df/dx)/Cartesian",
                                         "monotonic (it 0-5)", "Pareto"], rows,
                        title="Static case, 10 Newton iterations: solver settings and h/dx against accuracy "
                              "and time (Pareto: among all rows; the h/dx rows differ in accuracy by the "
                              "kernel's own error)")
    return table, rows, points


def kinematic_sweep(out, ranks, sweep=FULL):
    rows, points = [], []
    cases = [(ratio, beta, *DEFAULT_SOLVER) for ratio in sweep["kinematic_ratios"] for beta in sweep["betas"]]
    cases += [(2.0, 10.0, pc, rtol) for pc, rtol in sweep["solvers"] if (pc, rtol) != DEFAULT_SOLVER]
    for ratio, beta, pc, rtol in cases:
        default = (pc, rtol) == DEFAULT_SOLVER
        try:
            run = run_scene(CASES / "kinematic_tgv.toml",
                            out / (f"kin_h{ratio}_b{beta}" + ("" if default else f"_{pc}_{rtol}")), ranks=ranks,
                            sets=[f"domain.dx={sweep['kinematic_dx']}", f"domain.h_over_dx={ratio}",
                                  f"time.t_end={sweep['t_end']}", f"iips.beta={beta}", "iips.max_newton=50",
                                  "iips.on_failure=warn", "iips.on_stall=warn", "output.every=0", *PCS[pc][1]],
                            petsc=[] if default else ["-iips_pc_type", PCS[pc][0], "-iips_ksp_rtol", str(rtol)])
        except RunStopped as exc:  # a diverged KSP solve stops even a "warn" run: a result of the sweep
            rows.append([ratio, beta, pc, rtol, "failed: " + stop_message(exc)[:80]] + ["-"] * 6)
            print(rows[-1], flush=True)
            continue
        s = run.summary
        linf = [r["Linf_grad_c"] for r in run.history[1:]]
        mean_linf = sum(linf) / len(linf)
        rows.append([ratio, beta, pc, rtol, s["pre_procedure_linf"], s["step_time_s"],
                     s["newton_iterations"] / s["steps"], s["linear_iterations"], s["failed_calls"], mean_linf,
                     s["final"]["L2_dfdx"]])
        points.append((s["step_time_s"], s["final"]["L2_dfdx"]))
        print(rows[-1], flush=True)
    header = ["h/dx", "beta", "PC", "KSP rtol", "Linf(grad C) after the pre-procedure", "step time [s]",
              "Newton it. per step", "KSP iterations", "failed calls (stalls)", "mean Linf(grad C)", "final L2(df/dx)"]
    table = write_table(out / "kinematic", header, rows,
                        title=f"Kinematic case (dx = {sweep['kinematic_dx']}, t = {sweep['t_end']}, Procedure B): "
                              "threshold, h/dx and solver against cost (threshold = beta x the pre-procedure's "
                              "Linf(grad C), which the solver settings change)")
    return table, rows, points


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/iips_tradeoff"))
    parser.add_argument("--ranks", type=positive_int, default=1)
    parser.add_argument("--quick", action="store_true", help="a smoke run: coarse, short and few cases (above)")
    args = parse_args(parser)
    sweep = QUICK if args.quick else FULL
    quick = [f"domain.dx={sweep['static_dx']}"] if args.quick else []  # (the full study's at the scene's dx)
    run_scene(CASES / "static_perturbed.toml", args.out / "warmup", sets=["shifting.method=iips", "iips.max_newton=1",
                                                                         *quick])
    static_table, static_rows, static_points = static_sweep(args.out, args.ranks, sweep)
    kin_table, kin_rows, kin_points = kinematic_sweep(args.out, args.ranks, sweep)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    markers = {"jacobi": "o", "jacobi_assembled": "D", "hypre": "s", "gamg": "^"}
    colours = {0.1: "C3", 0.01: "C0", 1e-6: "C2"}
    for row, (t, e) in zip([r for r in static_rows if not isinstance(r[3], str)], static_points):
        axes[0].loglog(t, e, markers[row[1]], color=colours[row[2]], mfc="none" if row[0] != 2.0 else None)
        axes[0].annotate(f"{row[1]}, {row[2]:g}" + ("" if row[0] == 2.0 else f", h/dx={row[0]:g}"), (t, e),
                         fontsize=7)
    axes[0].set(xlabel="shifting time [s]", ylabel="L2(grad C) after 10 iterations",
                title=f"static, dx = {sweep['static_dx']}")
    for row, (t, e) in zip([r for r in kin_rows if not isinstance(r[4], str)], kin_points):
        default = (row[2], row[3]) == DEFAULT_SOLVER
        axes[1].loglog(t, e, markers[row[2]], color={2.0: "C0", 1.6: "C1", 1.3: "C4"}[row[0]] if default
                       else colours[row[3]])
        axes[1].annotate(f"h/dx={row[0]:g}, beta={row[1]:g}" if default else f"{row[2]}, {row[3]:g}", (t, e),
                         fontsize=7)
    axes[1].set(xlabel="time-loop wall time [s]", ylabel="final L2(d f/dx)",
                title=f"kinematic, dx = {sweep['kinematic_dx']}, t = {sweep['t_end']}")
    fig.tight_layout()
    fig.savefig(args.out / "tradeoff.png", dpi=120)
    print(static_table)
    print(kin_table)


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
