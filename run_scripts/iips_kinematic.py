"""IIPS kinematic test case (thesis 000 section 8.3.2): particles advected by the frozen Taylor-Green
field; Procedures A, B (beta = 5, 10) and the explicit Procedure C compared by their Linf(grad C) and
L2(d f/dx) histories and cost (figs 8.10-8.12), and by the convergence of L2(d f/dx) with dx for
h/dx = 2.0, 1.6, 1.3 (Table 8.3).

    .venv/bin/python run_scripts/iips_kinematic.py [--t-end 0.2] [--ranks 2] [--out results/iips_kinematic]

Every run: 100-iteration static pre-procedure from sigma/dx = 0.1, U = 1, c0 = 10, dt = 0.2 dx / c0,
test wavelength l = L (thesis eq. 3.6 with its lambda/L = 0.5 read literally: f = sin(2 pi x) + cos(2 pi y),
so that the error of the particle distribution, not the kernel's smoothing error, dominates), IIPS stalls
reported and counted (on_failure = on_stall = warn). Procedure C is eq. 8.36: one explicit step per time step with
D = (c0 dt)^2.
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from psph.studies import CASES, parse_args, positive_float, positive_int, rate, run_scene, smoothing_ratio, write_table  # noqa: E402

SCENE = CASES / "kinematic_tgv.toml"
PROCEDURES = {  # name: (directory tag, scene overrides)
    "A": ("A", ["shifting.method=iips", "iips.procedure=A", "iips.beta=5"]),
    "B, beta=5": ("B5", ["shifting.method=iips", "iips.procedure=B", "iips.beta=5"]),
    "B, beta=10": ("B10", ["shifting.method=iips", "iips.procedure=B", "iips.beta=10"]),
    "C (explicit)": ("C", ["shifting.method=explicit_iterative", "shifting.iterations_per_step=1"]),
}


def sets_for(name, dx, ratio, t_end):
    base = [f"domain.dx={dx}", f"domain.h_over_dx={ratio}", f"time.t_end={t_end}", "iips.pre_newton=100",
            "iips.max_newton=50", "iips.on_failure=warn", "iips.on_stall=warn", "output.every=0",
            "output.history_every=5"]
    extra = list(PROCEDURES[name][1])
    if name.startswith("C"):
        extra.append(f"shifting.diffusion={(0.2 / ratio) ** 2}")  # D = (c0 dt)^2 = (0.2 dx)^2
    return base + extra


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/iips_kinematic"))
    parser.add_argument("--ranks", type=positive_int, default=1)
    parser.add_argument("--t-end", type=positive_float, default=0.2)
    parser.add_argument("--resolutions", type=positive_float, nargs="+", default=[0.05, 0.025, 0.0125])
    parser.add_argument("--ratios", type=smoothing_ratio, nargs="+", default=[2.0, 1.6, 1.3])
    args = parse_args(parser)
    runs = {}
    for ratio in args.ratios:
        for dx in args.resolutions:
            for name in PROCEDURES:
                out = args.out / f"{PROCEDURES[name][0]}_dx{dx}_h{ratio}"
                runs[(name, dx, ratio)] = run_scene(SCENE, out, sets=sets_for(name, dx, ratio, args.t_end),
                                                    ranks=args.ranks)
                s = runs[(name, dx, ratio)].summary
                print(f"{name:13s} dx={dx} h/dx={ratio}: L2(df/dx)={s['final']['L2_dfdx']:.4e} "
                      f"Linf(gradC)={s['final']['Linf_grad_c']:.3e} step time {s['step_time_s']:.1f} s "
                      f"stalls {s['failed_calls']}", flush=True)

    # histories and cost at dx = 0.025 (or the middle resolution), h/dx = 2 (figs 8.10-8.12)
    dx_mid = args.resolutions[len(args.resolutions) // 2]
    ratio0 = args.ratios[0]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    cost_rows = []
    t_c = runs[("C (explicit)", dx_mid, ratio0)].summary["step_time_s"]
    for name in PROCEDURES:
        run = runs[(name, dx_mid, ratio0)]
        h = run.history
        axes[0].semilogy([r["time"] for r in h], [r["Linf_grad_c"] for r in h], label=name)
        axes[1].semilogy([r["time"] for r in h], [r["L2_dfdx"] for r in h], label=name)
        s = run.summary
        linf = np.array([r["Linf_grad_c"] for r in h[1:]])
        cost_rows.append([name, s["step_time_s"], s["step_time_s"] / t_c, s["shifting_time_s"],
                          s.get("newton_iterations", 0) / max(s["steps"], 1), s["failed_calls"],
                          float(np.mean(linf)), s["final"]["L2_dfdx"]])
    axes[0].set(xlabel="t", ylabel="Linf(grad C)")
    axes[1].set(xlabel="t", ylabel="L2(d f/dx)")
    axes[0].legend()
    fig.suptitle(f"kinematic Taylor-Green, dx = {dx_mid}, h/dx = {ratio0}")
    fig.tight_layout()
    fig.savefig(args.out / "histories.png", dpi=120)
    print(write_table(
        args.out / "cost", ["procedure", "step time [s]", "relative to C", "shifting time [s]",
                            "Newton iterations per step", "stalled calls", "mean Linf(grad C)", "final L2(df/dx)"],
        cost_rows, title=f"Kinematic case, dx = {dx_mid}, h/dx = {ratio0}, t = {args.t_end}: cost (thesis fig. 8.12)",
        note="step time = shifting + advection + history diagnostics of the time loop (the pre-procedure excluded)."))

    rows = []
    for ratio in args.ratios:
        row = [ratio]
        for name in PROCEDURES:
            e = [runs[(name, dx, ratio)].summary["final"]["L2_dfdx"] for dx in args.resolutions]
            row += [rate(e[k], e[k + 1], args.resolutions[k] / args.resolutions[k + 1]) for k in range(len(e) - 1)]
        rows.append(row)
    header = ["h/dx"]
    for name in PROCEDURES:
        header += [f"{name}: theta_{k + 1}" for k in range(len(args.resolutions) - 1)]
    errors = [[name, ratio] + [runs[(name, dx, ratio)].summary["final"]["L2_dfdx"] for dx in args.resolutions]
              for ratio in args.ratios for name in PROCEDURES]
    write_table(args.out / "errors", ["procedure", "h/dx"] + [f"L2(df/dx) at dx={dx}" for dx in args.resolutions],
                errors, title=f"Kinematic case: L2(d f/dx) after the last step's shifting (t = {args.t_end} - dt)")
    print(write_table(args.out / "table_8_3", header, rows,
                      title=f"Kinematic case: convergence rates of L2(d f/dx) at t = {args.t_end} - dt "
                            "(thesis Table 8.3)",
                      note=f"dx/L = {', '.join(map(str, args.resolutions))}; theta_k between successive resolutions."))
    print((args.out / "errors.md").read_text())


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
