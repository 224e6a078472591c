"""Shared fixtures. Tests marked `mpi` run on 1, 2 and 3 ranks (run_scripts/test.sh)."""

import os

import numpy as np
import pytest

os.environ.setdefault("H5PY_ALWAYS_USE_MPI", "1")


@pytest.fixture
def comm():
    """The test's communicator (the tests are the application: they own COMM_WORLD)."""
    from mpi4py import MPI

    return MPI.COMM_WORLD


def periodic_scene(dim=2, n=20, kernel="wendland_c6", h_over_dx=2.0, sigma=0.0, seed=3, name="test", **sections):
    """A validated bi-periodic unit-box scene with n particles per axis."""
    from psph.scene.load import scene_from_table

    table = {"name": name,
             "domain": {"dimension": dim, "lower": [0.0] * dim, "upper": [1.0] * dim, "periodic": [True] * dim,
                        "dx": 1.0 / n, "h_over_dx": h_over_dx, "kernel": kernel},
             "initial": {"sigma_over_dx": sigma, "seed": seed}}
    for key, value in sections.items():
        table.setdefault(key, {}).update(value)
    return scene_from_table(table)


def gather_by_gid(comm, gid, values):
    """All ranks' owned `values`, ordered by gid (on every rank)."""
    gids = np.concatenate(comm.allgather(np.asarray(gid)))
    vals = np.concatenate(comm.allgather(np.asarray(values)))
    order = np.argsort(gids)
    return gids[order], vals[order]


@pytest.fixture(autouse=True)
def collect_garbage_together():
    """Under mpiexec, after every test, collect the garbage it left in reference cycles (petsc4py wrappers
    among it: an exception path leaves them) on every rank at the same point. Left to the collector, each
    rank frees them at its own moment, and PETSc's communicator pools (hypre's, MUMPS') then differ between
    the ranks (psph.solvers.petsc.petsc_comm, README "Known issues"; details in docs/results.md)."""
    yield
    from mpi4py import MPI

    if MPI.COMM_WORLD.size > 1:
        import gc

        gc.collect()


@pytest.fixture(autouse=True)
def close_serial_drivers(monkeypatch):
    """Close, when a test ends, the one-rank drivers it made and left open, as the `with` block of `psph run`
    closes its driver: their PETSc objects and communicators are freed then, not whenever the collector runs
    (psph.drivers.base.Driver). A driver on more ranks is left to its test: a close here, collective, would
    wait for a rank whose test made none."""
    from psph.drivers.fluid import FluidDriver
    from psph.drivers.kinematic import KinematicDriver
    from psph.drivers.static import StaticDriver

    made = []

    def registering(init):
        def __init__(self, *args, **kwargs):
            init(self, *args, **kwargs)
            made.append(self)
        return __init__

    for cls in (FluidDriver, KinematicDriver, StaticDriver):
        monkeypatch.setattr(cls, "__init__", registering(cls.__init__))
    yield
    for driver in made:
        if not driver.closed and driver.sim.comm.size == 1:
            driver.close()


def pytest_collection_modifyitems(items):
    """The tests marked `long` first. With tests handed out one at a time (run_scripts/test.sh:
    --maxschedchunk 1; by default pytest-xdist gives each worker a block of consecutive tests), each worker
    starts on long ones and the short ones fill in after: a long test late in the order kept one worker busy
    for minutes after the other had finished."""
    items.sort(key=lambda item: item.get_closest_marker("long") is None)


def pytest_runtest_logreport(report):
    """Under mpiexec, a failure on one rank would leave the others waiting in a collective: print the
    failure and abort every rank instead (the run fails loudly rather than hanging)."""
    if report.failed:
        from mpi4py import MPI

        comm = MPI.COMM_WORLD
        if comm.size > 1:
            import sys

            sys.stderr.write(f"\n[rank {comm.rank}] FAILED {report.nodeid}\n{report.longreprtext}\n")
            sys.stderr.flush()
            comm.Abort(1)
