"""The static and kinematic drivers end to end give the same particles and history on 1, 2 and 3 ranks
(the shifting objects alone are compared in tests/shifting/test_iips_parallel.py): by gid against a
serial run of the same scene, with tight KSP tolerances."""

import numpy as np
import pytest
from mpi4py import MPI

from psph.drivers import driver_for
from psph.io.history import read_history
from psph.scene.load import load_scene
from tests.conftest import gather_by_gid
from tests.helpers import CASES
from tests.shifting.test_iips import petsc_options

pytestmark = pytest.mark.mpi

COLUMNS = ("L2_grad_c", "Linf_grad_c", "L2_dfdx", "newton", "iips_calls")


def run(scene, comm, out):
    """Final positions by gid, and the history's columns of COLUMNS it has."""
    with driver_for(scene)(scene, comm, out) as driver:
        driver.run()
        p = driver.sim.system.particles
        result = {"position": gather_by_gid(comm, p.owned("gid"), p.owned("position"))[1]}
    comm.Barrier()  # rank 0 wrote the history
    rows = read_history(out / "history.csv")
    result.update({k: np.array([r[k] for r in rows], dtype=float) for k in COLUMNS if k in rows[0]})
    return result


@pytest.mark.parametrize("case,sets,tol", [
    ("static_perturbed.toml", ["shifting.method=iips", "iips.max_newton=4", "initial.sigma_over_dx=0.25"], 1e-9),
    ("static_perturbed.toml", ["shifting.method=explicit_iterative", "shifting.max_iterations=30"], 1e-12),
    ("kinematic_tgv.toml", ["iips.pre_newton=10", "time.t_end=0.02"], 1e-9),
    ("kinematic_tgv.toml", ["iips.pre_newton=10", "time.t_end=0.02", "iips.procedure=A", "iips.beta=0",
                            "iips.threshold=1e-3"], 1e-9),
    ("kinematic_tgv.toml", ["time.t_end=0.02", "iips.pre_newton=0", "iips.beta=0", "shifting.method=explicit_iterative",
                            "shifting.iterations_per_step=1", "shifting.diffusion=0.01"], 1e-12),
    ("kinematic_tgv.toml", ["time.t_end=0.02", "iips.pre_newton=0", "iips.beta=0", "shifting.method=neuhauser"],
     1e-12),  # an explicit law's transport velocity (its memory read across the halo)
    ("kinematic_tgv.toml", ["time.t_end=0.02", "iips.pre_newton=0", "iips.beta=0", "shifting.method=delta_plus"],
     1e-12),
])
def test_static_and_kinematic_runs_match_serial(comm, mpi_tmp_path, case, sets, tol):
    scene = load_scene(CASES / case, ["domain.dx=0.05", "output.every=0", *sets])
    with petsc_options(iips_ksp_rtol=1e-13, iips_ksp_atol=1e-30):
        parallel = run(scene, comm, mpi_tmp_path / "par")
        serial = run(scene, MPI.COMM_SELF, mpi_tmp_path / f"ser{comm.rank}")
    assert parallel.keys() == serial.keys() and len(parallel) > 2
    for k in parallel:
        assert parallel[k].shape == serial[k].shape, k
        scale = max(np.abs(serial[k]).max(), 1e-3)
        assert np.abs(parallel[k] - serial[k]).max() <= tol * scale, k
