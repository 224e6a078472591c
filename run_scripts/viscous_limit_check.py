"""How close the viscous time-step limit's estimate of lambda_max is to the true one (psph.schemes.viscous_limit).

    .venv/bin/python run_scripts/viscous_limit_check.py [--out results/viscous_limit] [--ratios 1.2 1.5 2.0 2.5]
                                                        [--kernels wendland_c6 ...]

For every kernel, h/dx and viscous operator (pi_ij of seed 001 eq. 11, Morris'), on a periodic 2-D lattice
as it is, perturbed (sigma = 0.25, 0.5, 0.8 dx), stretched (1.5 and 2 times along x, squeezed along y) and
both (0.3 dx, 1.5 times): the largest eigenvalue of the assembled operator (psph.studies.
viscous_operator_on_lattice) against the estimate the run uses (the lattice symbol scaled by the largest
diagonal weight). A ratio estimate / true below SAFETY would let a step exceed the integrator's stability;
far above 1 costs steps. Writes estimate.md / estimate.csv; exits 1 if any ratio is below SAFETY. --kernels
checks some of the kernels only (default: every one).
"""

import argparse
import itertools
from pathlib import Path

import numpy as np

from psph.compute.smoothing import KERNEL_NAMES
from psph.schemes.viscous_limit import SAFETY, lattice_symbol
from psph.studies import parse_plain, smoothing_ratio, viscous_operator_on_lattice, write_table

CASES = ((0.0, 1.0), (0.25, 1.0), (0.5, 1.0), (0.8, 1.0), (0.0, 1.5), (0.0, 2.0), (0.3, 1.5))  # (sigma, stretch)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/viscous_limit"))
    parser.add_argument("--ratios", type=smoothing_ratio, nargs="+", default=[1.2, 1.5, 2.0, 2.5], help="h/dx")
    parser.add_argument("--kernels", nargs="+", default=list(KERNEL_NAMES), choices=KERNEL_NAMES,
                        help="the kernels checked (default: all)")
    args = parse_plain(parser)
    rng = np.random.default_rng(3)
    rows, ratios = [], []
    for kernel, h_over_dx, morris in itertools.product(args.kernels, args.ratios, (False, True)):
        row = [kernel, h_over_dx, "Morris" if morris else "pi_ij"]
        for sigma, stretch in CASES:
            matrix, dx, kern, diagonal = viscous_operator_on_lattice(12, 2, h_over_dx, morris, sigma, rng, kernel,
                                                                     stretch)
            true = -np.linalg.eigvals(matrix).real.min()
            largest, lattice_diagonal = lattice_symbol(kern, 2, dx, morris)
            ratios.append(largest * max(1.0, diagonal / lattice_diagonal) / true)
            row.append(f"{ratios[-1]:.2f}")
        rows.append(row)
        print(" ".join(map(str, row)), flush=True)
    header = ["kernel", "h/dx", "operator"] + [f"sigma {s:g} dx, stretch {a:g}" for s, a in CASES]
    note = (f"estimate / true lambda_max over {len(ratios)} cases: {min(ratios):.2f} to {max(ratios):.2f}; the "
            f"limit takes SAFETY = {SAFETY:g} of the estimated step, stable while the ratio stays above it")
    print(write_table(args.out / "estimate.md", header, rows, title="The viscous limit's estimate of lambda_max "
                      "against the assembled operator's (2-D periodic lattices of 144 particles)", note=note))
    return 1 if min(ratios) < SAFETY else 0


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
