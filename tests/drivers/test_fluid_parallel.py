"""The fluid solver gives the same answer on 1, 2 and 3 ranks: to round-off with an explicit shifting law,
to the linear-solver tolerance with IIPS (compared by gid with a serial run of the same scene)."""

import numpy as np
import pytest
from mpi4py import MPI

from psph.drivers.fluid import FluidDriver
from tests.conftest import gather_by_gid, periodic_scene
from tests.shifting.test_iips import petsc_options

pytestmark = pytest.mark.mpi


def run(scene, comm, out):
    driver = FluidDriver(scene, comm, out)
    driver.run()
    p = driver.system.particles
    return {k: gather_by_gid(comm, p.owned("gid"), p.owned(k))[1] for k in ("position", "velocity", "density")}


def assert_matches_serial(scene, comm, tmp, tol):
    """Positions, velocities and densities of a run on `comm` equal a serial run's by gid, within tol."""
    with petsc_options(iips_ksp_rtol=1e-12, iips_ksp_atol=1e-30):
        parallel = run(scene, comm, tmp / "par")
        serial = run(scene, MPI.COMM_SELF, tmp / f"ser{comm.rank}")
    for k in parallel:
        scale = max(np.abs(serial[k]).max(), 1.0)
        assert np.abs(parallel[k] - serial[k]).max() < tol * scale, k


@pytest.mark.parametrize("shifting,update,viscosity,relaxed,tol", [
    ("delta_plus", "none", "monaghan", False, 1e-11), ("iips", "nfts", "monaghan", False, 1e-7),
    ("iips", "mls2", "monaghan", False, 1e-7), ("iips", "mls2", "morris", False, 1e-7),
    ("iips", "mls2", "morris", True, 1e-7), ("delta_plus", "none", "monaghan", True, 1e-7)])
def test_fluid_run_matches_serial(comm, mpi_tmp_path, shifting, update, viscosity, relaxed, tol):
    """relaxed: a perturbed lattice levelled by the IIPS pre-procedure first (iips.pre_newton)."""
    scene = periodic_scene(n=16, initial={"velocity": "taylor_green", "sigma_over_dx": 0.25 if relaxed else 0.0},
                           physics={"scheme": "delta_ale", "viscosity": viscosity},
                           time={"t_end": 0.04}, shifting={"method": shifting},
                           iips={"update": update, "threshold": 1e-3, "pre_newton": 20 if relaxed else 0})
    assert_matches_serial(scene, comm, mpi_tmp_path, tol)


@pytest.mark.parametrize("shifting,update,thesis,tol", [
    ("neuhauser", "none", False, 1e-11), ("iips", "nfts", False, 1e-7), ("iips", "mls2", False, 1e-7),
    ("iips", "nfts", True, 1e-7)])
def test_riemann_ale_run_matches_serial(comm, mpi_tmp_path, shifting, update, thesis, tol):
    """The Riemann SPH-ALE scheme: its MUSCL gradients of the halo particles are exchanged like the fields.
    thesis: the set-up of cases/taylor_green_thesis.toml (no limiter, Morris' operator, relaxed start)."""
    physics = {"scheme": "riemann_ale"}
    if thesis:
        physics.update(muscl_limiter="none", viscosity="morris")
    scene = periodic_scene(n=16, initial={"velocity": "taylor_green", "sigma_over_dx": 0.25 if thesis else 0.0},
                           physics=physics, time={"t_end": 0.04}, shifting={"method": shifting},
                           iips={"update": update, "threshold": 1e-3, "pre_newton": 20 if thesis else 0})
    assert_matches_serial(scene, comm, mpi_tmp_path, tol)


@pytest.mark.parametrize("case,sets,tol", [
    ("lid_driven_cavity.toml", ["shifting.method=delta_plus"], 1e-11),
    ("lid_driven_cavity.toml", ["shifting.method=iips", "iips.threshold=0.02", "iips.update=nfts",
                               "initial.sigma_over_dx=0.05"], 1e-7),
    ("lid_driven_cavity.toml", ["shifting.method=iips", "iips.threshold=0.02", "iips.update=mls2_increment",
                               "initial.sigma_over_dx=0.05"], 1e-7),
    ("lid_driven_cavity.toml", ["shifting.method=delta_plus", "physics.viscosity=morris"], 1e-11),
    ("hydrostatic_tank.toml", [], 1e-11),
    ("inclined_ellipse.toml", ["domain.dx=0.2", "physics.free_stream_ramp=0.05"], 1e-11),
    ("moving_square.toml", ["domain.dx=0.1", "time.t_end=0.3", "bodies.1.center=[4.6, 2.5]",
                            "bodies.1.motion.law=ramp", "bodies.1.motion.ramp_time=0.1",
                            "bodies.1.motion.velocity=[0.3, 0.0]",
                            "bodies.1.motion.angular_velocity=0.5"], 1e-11)])
def test_runs_with_walls_match_serial(comm, mpi_tmp_path, case, sets, tol):
    """Walls across ranks: solid particles in halos, the clones mirrored from each rank's own fluid rows.
    The moving square, put across the ranks' border and turning as it translates, carries its solid
    particles from rank to rank."""
    from psph.scene.load import load_scene
    from tests.helpers import CASES

    scene = load_scene(CASES / case, ["domain.dx=0.05", "time.t_end=0.05", "output.every=0", *sets])
    assert_matches_serial(scene, comm, mpi_tmp_path, tol)


def test_ghost_walls_match_serial(comm, mpi_tmp_path):
    """Ghost walls across ranks: each rank mirrors its owned and halo fluid rows."""
    from psph.scene.load import apply_overrides, scene_from_table
    from tests.scene.test_scene import ghost_cavity

    table = apply_overrides(ghost_cavity(), ["domain.dx=0.05", "time.t_end=0.05", "output.every=0"])
    assert_matches_serial(scene_from_table(table), comm, mpi_tmp_path, 1e-11)
