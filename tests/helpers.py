"""Helpers for tests that run the command line."""

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
