"""IIPS static test case (thesis 000 section 8.3.1): Newton histories (figs 8.5) and the convergence
table of the SPH derivative after IIPS (Table 8.1).

    .venv/bin/python run_scripts/iips_static.py [--out results/iips_static] [--ranks 2] [--quick]
                                                [--resolutions 0.05 0.025] [--ratios 2.0 1.6 1.3]

Writes results/iips_static/{histories,table_8_1}.{md,csv} and histories.png. Definitions: lattice +
Gaussian perturbation of standard deviation sigma (per axis), Wendland C6, bi-periodic unit box; test
function f = sin(2 pi x / l) + cos(2 pi y / l) with wavelength l (l / dx particles per wavelength; the
thesis' lambda reads as l = lambda / 2, matching its "40, 20, 10 particles per wavelength" at
dx = 0.0125); KSP rtol 1e-2 (the default). Resolutions dx/L: 0.05, 0.025, 0.0125 (Table 8.1 adds 0.00625);
--quick: 0.05 and 0.025 in both; --resolutions: the given ones in both. --ratios: the h/dx of Table 8.1
(2, 1.6, 1.3). `--resolutions 0.1 --ratios 2` is the smoke run of tests/test_run_scripts.py.
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from psph.studies import (  # noqa: E402
    CASES,
    first_iteration,
    parse_args,
    positive_float,
    positive_int,
    rate,
    run_scene,
    smoothing_ratio,
    write_table,
)

SCENE = CASES / "static_perturbed.toml"


def histories(out, ranks, resolutions, sigmas, iterations):
    rows, curves = [], {}
    for dx in resolutions:
        for sigma in sigmas:
            run = run_scene(SCENE, out / f"dx{dx}_s{sigma}", ranks=ranks, sets=[
                f"domain.dx={dx}", f"initial.sigma_over_dx={sigma}", "shifting.method=iips",
                f"iips.max_newton={iterations}"])
            h = run.history
            cart = h[0]["L2_dfdx_cartesian"]
            l2 = [r["L2_grad_c"] for r in h]
            thousand = first_iteration(h, lambda r, l0=l2[0]: r["L2_grad_c"] <= 1e-3 * l0)
            within = first_iteration(h, lambda r, c=cart: r["L2_dfdx"] <= 1.05 * c)
            best = min(range(len(l2)), key=l2.__getitem__)
            # IIPS may stop before iteration 5 (converged, or a lattice it leaves as it is):
            # "-" for what it did not reach
            fifth = l2[min(5, iterations)] if len(l2) > min(5, iterations) else None
            rows.append([dx, sigma, run.summary["n_particles"], l2[0], fifth,
                         l2[0] / fifth if fifth else None, l2[0] / l2[best] if l2[best] else None,
                         int(h[best]["iteration"]), int(thousand["iteration"]) if thousand else "never",
                         int(within["iteration"]) if within else "never", h[-1]["L2_dfdx"] / cart])
            curves[(dx, sigma)] = h
    table = write_table(
        out / "histories",
        ["dx/L", "sigma/dx", "particles", "L2(gradC) it 0", "L2(gradC) it 5", "drop at it 5", "best drop",
         "at it", "it to 1e-3 drop", "it to 5% of Cartesian L2(df/dx)", f"L2(df/dx)/Cartesian at it {iterations}"],
        rows, title="IIPS static case: Newton histories (thesis figs 8.5)",
        note="L2(grad C) as in thesis eq. 3.4; Cartesian = the unperturbed lattice at the same dx.")
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for (dx, sigma), h in curves.items():
        it = [r["iteration"] for r in h]
        style = "-" if sigma == sigmas[0] else "--"
        axes[0].semilogy(it, [r["L2_grad_c"] for r in h], style, label=f"dx={dx}, sigma={sigma}")
        axes[1].semilogy(it, [r["L2_dfdx"] / r["L2_dfdx_cartesian"] for r in h], style)
    axes[0].set(xlabel="Newton iteration", ylabel="L2(grad C)")
    axes[1].set(xlabel="Newton iteration", ylabel="L2(df/dx) / Cartesian value")
    axes[1].axhline(1.05, color="k", lw=0.5)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "histories.png", dpi=120)
    return table


def table_8_1(out, ranks, resolutions, ratios, iterations=10):
    rows = []
    errors = {}
    for dx in resolutions:
        row = [dx]
        for ratio in ratios:
            run = run_scene(SCENE, out / f"t81_dx{dx}_h{ratio}", ranks=ranks, sets=[
                f"domain.dx={dx}", f"domain.h_over_dx={ratio}", "initial.sigma_over_dx=0.1",
                "shifting.method=iips", f"iips.max_newton={iterations}"])
            e = run.history[-1]["L2_dfdx"]
            cart = run.history[0]["L2_dfdx_cartesian"]
            coarser = resolutions[resolutions.index(dx) - 1] if dx != resolutions[0] else None
            prev = errors.get((ratio, coarser))
            errors[(ratio, dx)] = e
            row += [e, rate(prev, e, coarser / dx) if prev else float("nan"), e / cart]
        rows.append(row)
    header = ["dx/L"]
    for ratio in ratios:
        header += [f"h/dx={ratio}: L2(df/dx)", "rate", "/ Cartesian"]
    return write_table(out / "table_8_1", header, rows,
                       title=f"IIPS static case: L2(df/dx) after {iterations} Newton iterations (thesis Table 8.1)",
                       note="sigma/dx = 0.1; rate = the observed order between successive dx, "
                            "log(error ratio) / log(dx ratio).")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/iips_static"))
    parser.add_argument("--ranks", type=positive_int, default=1)
    parser.add_argument("--quick", action="store_true", help="coarse resolutions only (a smoke run)")
    parser.add_argument("--resolutions", type=positive_float, nargs="+",
                        help="dx/L of both the histories and Table 8.1 (default: 0.05 0.025 0.0125, and 0.00625 "
                             "in Table 8.1; --quick: 0.05 0.025)")
    parser.add_argument("--ratios", type=smoothing_ratio, nargs="+", default=[2.0, 1.6, 1.3], help="h/dx of Table 8.1")
    args = parse_args(parser)
    args.out.mkdir(parents=True, exist_ok=True)  # (parse_args checked that it can be)
    res = args.resolutions or ([0.05, 0.025] if args.quick else [0.05, 0.025, 0.0125])
    print(histories(args.out, args.ranks, res, [0.10, 0.25], 10))
    print(table_8_1(args.out, args.ranks, res if args.quick or args.resolutions else res + [0.00625], args.ratios))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
