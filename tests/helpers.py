"""Helpers for tests: running the command line, a perturbed particle lattice."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = ROOT / "cases"


def mpi_environment() -> dict:
    """This process's environment without its MPI context (a test under mpiexec must not leak it)."""
    return {k: v for k, v in os.environ.items()
            if not k.startswith(("OMPI_COMM", "PMIX", "OMPI_MCA_orte", "OMPI_FILE"))}


def run_psph(*args, ranks=1, timeout=300, cwd=None):
    """Run `python -m psph ARGS` (under mpiexec for ranks > 1); returns the CompletedProcess."""
    cmd = [sys.executable, "-m", "psph", *map(str, args)]
    if ranks > 1:
        cmd = ["mpiexec", "-n", str(ranks), "--oversubscribe"] + cmd
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=cwd or ROOT,
                          env=mpi_environment())


def perturbed_lattice(rng, dim, n_side):
    """A lattice of the unit box perturbed by 0.2 dx, volumes within 10% of dx^d, Wendland C6 at h/dx = 1.6,
    neighbour lists with a skin as in runs: (pos, vol, kernel, ptr, idx)."""
    import numpy as np

    from psph.compute.neighbours import build_neighbour_lists
    from psph.compute.smoothing import make_kernel

    dx = 1.0 / n_side
    grid = np.stack(np.meshgrid(*[np.arange(n_side) * dx] * dim, indexing="ij"), axis=-1).reshape(-1, dim)
    pos = np.ascontiguousarray(grid + 0.2 * dx * rng.standard_normal(grid.shape))
    kern = make_kernel("wendland_c6", dim, 1.6 * dx)
    ptr, idx = build_neighbour_lists(pos, len(pos), 1.1 * kern.support)
    vol = dx**dim * (1.0 + 0.1 * rng.random(len(pos)))
    return pos, vol, kern, ptr, idx
