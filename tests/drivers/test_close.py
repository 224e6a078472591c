"""A driver used as a context manager frees its PETSc objects and communicators when its block ends, on every
rank at that point: after a run, a requested stop or a failure raised on every rank (psph.drivers.base)."""

import pytest
from mpi4py import MPI

from psph.drivers import driver_for
from psph.errors import NumericalError, PsphError
from psph.solvers import petsc as petsc_module
from tests.conftest import periodic_scene
from tests.shifting.test_iips import petsc_options

pytestmark = pytest.mark.mpi

IIPS = {"shifting": {"method": "iips"}, "iips": {"threshold": 1e-3, "max_newton": 3}}
SCENES = {
    "static": dict(sigma=0.2, **IIPS),
    "kinematic": dict(sigma=0.2, physics={"scheme": "kinematic"}, time={"t_end": 0.02}, **IIPS),
    # a threshold below reach: the lattice start needs IIPS iterations too (the stalls are kept and counted)
    "fluid": dict(initial={"velocity": "taylor_green"}, physics={"scheme": "delta_ale"}, time={"t_end": 0.01},
                  shifting={"method": "iips"}, iips={"threshold": 1e-12, "max_newton": 2}),
}


def anchors():
    return dict(petsc_module._anchors)


def assert_closed(driver, anchors_before, anchors_during):
    """The IIPS solver and its operator destroyed, the simulation's and system's communicators freed, and the
    vectors that kept PETSc's duplicates of them alive (on more than one rank) destroyed and dropped."""
    iips = driver.shifting_methods()[0]
    assert driver.closed
    assert iips.solver.ksp.handle == 0 and iips.operator.mat is None
    assert driver.sim.comm == MPI.COMM_NULL and driver.sim.system.comm == MPI.COMM_NULL
    assert anchors() == anchors_before
    assert all(vec.handle == 0 for key, vec in anchors_during.items() if key not in anchors_before)


@pytest.mark.parametrize("kind", sorted(SCENES))
def test_a_driver_frees_its_solvers_and_communicators_when_its_block_ends(comm, mpi_tmp_path, kind):
    scene = periodic_scene(n=12, **SCENES[kind])
    before = anchors()
    with driver_for(scene)(scene, comm, mpi_tmp_path / kind) as driver:
        driver.run()
        iips = driver.shifting_methods()[0]
        assert iips.solver.ksp.handle != 0 and iips.operator.mat is not None
        during = anchors()
        assert len(during) == len(before) + (2 if comm.size > 1 else 0)  # one rank: PETSc needs no anchor
    assert_closed(driver, before, during)
    driver.close()  # a second close does nothing


def test_a_failure_on_every_rank_frees_them_too(comm, mpi_tmp_path):
    """A diverged IIPS solve (iips.on_failure = "stop") raises on every rank: the block's end frees all."""
    scene = periodic_scene(n=12, sigma=0.2, **IIPS)
    before = anchors()
    with petsc_options(iips_ksp_max_it=1, iips_ksp_rtol=1e-12), pytest.raises(NumericalError, match="DIVERGED"):
        with driver_for(scene)(scene, comm, mpi_tmp_path) as driver:
            during = anchors()
            driver.run()
    assert_closed(driver, before, during)


def test_a_constructor_that_fails_on_every_rank_frees_what_it_built(comm, mpi_tmp_path, monkeypatch):
    """The fluid driver's pre-procedure diverges inside its constructor: its Simulation is closed (its
    communicators freed), and so is the pre-procedure's own IIPS solver."""
    from psph.simulation import Simulation
    from psph.solvers.linear import LinearSolver

    closed, destroyed, close, destroy = [], [], Simulation.close, LinearSolver.destroy
    monkeypatch.setattr(Simulation, "close", lambda sim: closed.append(sim) or close(sim))
    monkeypatch.setattr(LinearSolver, "destroy", lambda solver: destroyed.append(solver) or destroy(solver))
    scene = periodic_scene(n=12, sigma=0.2, initial={"velocity": "taylor_green"}, physics={"scheme": "delta_ale"},
                           time={"t_end": 0.01}, shifting={"method": "iips"}, iips={"pre_newton": 3})
    before = anchors()
    with petsc_options(iips_ksp_max_it=1, iips_ksp_rtol=1e-12), pytest.raises(NumericalError, match="DIVERGED"):
        driver_for(scene)(scene, comm, mpi_tmp_path)
    assert len(closed) == 1 and closed[0].comm == MPI.COMM_NULL and closed[0].system.comm == MPI.COMM_NULL
    assert len(destroyed) == 1 and destroyed[0].ksp.handle == 0
    assert anchors() == before


def test_an_error_of_some_ranks_only_leaves_the_driver_open(comm, mpi_tmp_path):
    """An error that is not marked collective may be one rank's: closing (collective) could wait for ever for
    the other ranks, which the command line aborts instead. A caller that knows better closes it itself."""
    scene = periodic_scene(n=12, sigma=0.2, **IIPS)
    with pytest.raises(PsphError, match="one rank's"):
        with driver_for(scene)(scene, comm, mpi_tmp_path) as driver:
            raise PsphError("one rank's")
    assert not driver.closed and driver.sim.comm != MPI.COMM_NULL
    driver.close()
    assert driver.sim.comm == MPI.COMM_NULL
