"""A failure on one rank ends every rank promptly, with its message (no hang in a collective)."""

import subprocess
import sys
import textwrap
import time

import pytest

from tests.helpers import CASES, ROOT, mpi_environment

INJECT = textwrap.dedent("""
    import sys
    from mpi4py import MPI
    import psph.drivers.fluid as fluid
    from psph.errors import NumericalError
    from psph.cli import main

    original = fluid.FluidDriver.check
    def check(self, step, t, dt):
        if MPI.COMM_WORLD.rank == 1 and step == 5:
            if sys.argv[1] == "bug":
                raise RuntimeError("injected failure")
            raise NumericalError("injected numerical failure", step=step, time=t)
        return original(self, step, t, dt)
    fluid.FluidDriver.check = check
    sys.exit(main(["run", sys.argv[2], "--out", sys.argv[3], "--set", "domain.dx=0.05",
                   "--set", "time.t_end=100", "--quiet"]))
    """)


@pytest.mark.parametrize("kind,words", [("bug", "injected failure"), ("numerical", "injected numerical failure")])
def test_failure_on_rank_1_of_3_ends_the_job_within_seconds(tmp_path, kind, words):
    """Without the abort the other ranks would wait forever in the next collective (the run asks for
    t_end = 100, thousands of steps); the job must end within seconds of the failure."""
    script = tmp_path / "inject.py"
    script.write_text(INJECT)
    start = time.monotonic()
    proc = subprocess.run(["mpiexec", "-n", "3", "--oversubscribe", sys.executable, str(script), kind,
                           str(CASES / "taylor_green.toml"), str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=120, cwd=ROOT, env=mpi_environment())
    elapsed = time.monotonic() - start
    assert proc.returncode != 0
    assert words in proc.stderr and "rank 1" in proc.stderr, proc.stderr
    assert elapsed < 60, elapsed  # start-up (imports, numba cache, PETSc) is most of it
