"""IIPS on several ranks: the final positions of the static case match the serial run (by gid)."""

import numpy as np
import pytest
from mpi4py import MPI

from psph.shifting.explicit import ExplicitIterativeShifting
from psph.shifting.iips import ImplicitShifting
from psph.simulation import build_system
from tests.conftest import gather_by_gid, periodic_scene
from tests.shifting.test_iips import petsc_options

pytestmark = pytest.mark.mpi


@pytest.mark.parametrize("operator", ["assembled", "matrix_free"])
@pytest.mark.parametrize("dim,n", [(2, 24), (3, 8)])
def test_static_iips_positions_independent_of_rank_count(comm, dim, n, operator):
    """On several ranks, with either operator (the matrix-free one's halo unknowns come through its
    scatter), the serial assembled run's positions."""
    def scene_with(kind):
        return periodic_scene(dim=dim, n=n, sigma=0.15, iips={"max_newton": 6, "operator": kind})

    scene = scene_with(operator)
    with petsc_options(iips_ksp_rtol=1e-13, iips_ksp_atol=1e-30):
        par_shift = ImplicitShifting(scene.iips, comm)
        ser_shift = ImplicitShifting(scene_with("assembled").iips, MPI.COMM_SELF)
    parallel = build_system(scene, comm)
    serial = build_system(scene, MPI.COMM_SELF)
    a = par_shift.correct(parallel)
    b = ser_shift.correct(serial)
    assert a.iterations == b.iterations == 6
    gids, pos = gather_by_gid(comm, parallel.particles.owned("gid"), parallel.particles.owned("position"))
    order = np.argsort(serial.particles.owned("gid"))
    expect = serial.particles.owned("position")[order]
    assert np.array_equal(gids, np.arange(n**dim))
    assert np.abs(parallel.domain.minimum_image(pos - expect)).max() < 1e-8
    assert a.L2_grad_c == pytest.approx(b.L2_grad_c, rel=1e-6)


def test_backtracking_independent_of_rank_count(comm):
    """iips.backtrack = 1 at h/dx = 1.2, where the fifth full step raises L2(grad C) and the call ends back
    at the fourth iterate: the same iterations and positions on 1, 2 and 3 ranks (the step it halves and
    undoes is a field that migrates with the particles)."""
    scene = periodic_scene(n=20, h_over_dx=1.2, sigma=0.1, iips={"max_newton": 12, "backtrack": 1})
    with petsc_options(iips_ksp_rtol=1e-13, iips_ksp_atol=1e-30):
        par_shift = ImplicitShifting(scene.iips, comm)
        ser_shift = ImplicitShifting(scene.iips, MPI.COMM_SELF)
    parallel = build_system(scene, comm)
    serial = build_system(scene, MPI.COMM_SELF)
    a = par_shift.correct(parallel)
    b = ser_shift.correct(serial)
    assert a.iterations == b.iterations == 5 and a.message == b.message == ("IIPS call ended after 5 iterations: "
                                                                              "no descent in 1 halvings")
    _, pos = gather_by_gid(comm, parallel.particles.owned("gid"), parallel.particles.owned("position"))
    expect = serial.particles.owned("position")[np.argsort(serial.particles.owned("gid"))]
    assert np.abs(parallel.domain.minimum_image(pos - expect)).max() < 1e-8
    assert a.L2_grad_c == pytest.approx(b.L2_grad_c, rel=1e-6)


@pytest.mark.parametrize("dim,n", [(2, 12), (3, 6)])
def test_matrix_free_products_on_ranks_are_the_assembled_ones(comm, dim, n):
    """On several ranks, the matrix-free operator's product and transpose's product (through its halo
    scatter; the volumes made unequal, so that A^T differs from A) are the assembled matrix's."""
    from tests.shifting.test_iips import operator_products_and_diagonal

    scene = periodic_scene(dim=dim, n=n, sigma=0.2)
    system = build_system(scene, comm)
    volume = system.particles.owned("volume")
    volume *= 1.0 + 0.5 * np.random.default_rng(comm.rank + 5).random(len(volume))
    system.refresh(["volume"])
    vector = np.random.default_rng(comm.rank).standard_normal(dim * system.particles.n_owned)
    results = {}
    for operator in ("assembled", "matrix_free"):
        shifting = ImplicitShifting(periodic_scene(dim=dim, n=n, iips={"operator": operator}).iips, comm)
        results[operator] = operator_products_and_diagonal(shifting, system, vector)
        shifting.destroy()
    for a, f in zip(results["assembled"], results["matrix_free"]):
        scale = comm.allreduce(np.abs(a).max(), op=MPI.MAX)
        assert scale > 0 and comm.allreduce(np.abs(f - a).max(), op=MPI.MAX) < 1e-12 * scale


def test_explicit_shifting_independent_of_rank_count(comm):
    scene = periodic_scene(n=20, sigma=0.1, shifting={"method": "explicit_iterative"})
    parallel, serial = build_system(scene, comm), build_system(scene, MPI.COMM_SELF)
    ExplicitIterativeShifting(scene.shifting).correct(parallel, iterations=30)
    ExplicitIterativeShifting(scene.shifting).correct(serial, iterations=30)
    _, pos = gather_by_gid(comm, parallel.particles.owned("gid"), parallel.particles.owned("position"))
    expect = serial.particles.owned("position")[np.argsort(serial.particles.owned("gid"))]
    assert np.abs(parallel.domain.minimum_image(pos - expect)).max() < 1e-12


@pytest.mark.mpi(min_size=2)
@pytest.mark.parametrize("operator", ["assembled", "matrix_free"])
def test_iips_with_an_empty_rank(comm, operator):
    """A tiny fluid patch in walls, all of it on rank 0 of a non-periodic box whose other ranks own empty
    slabs (a fixed decomposition, never rebalanced): ranks without any particle take part in assembly (or
    the matrix-free product) and solve, and the result is the serial assembled one."""
    from psph.compute.smoothing import make_kernel
    from psph.domain import Domain
    from psph.parallel.decomposition import Decomposition, Split
    from psph.particles import Kind, ParticleSet
    from psph.system import ParticleSystem

    n = 6
    g = (np.arange(n) + 0.5) / n * 0.3
    lattice = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2) + 0.35
    lattice += np.random.default_rng(1).normal(0, 0.005, lattice.shape)
    kind = np.where(np.any((lattice < 0.42) | (lattice > 0.58), axis=1), Kind.WALL, Kind.FLUID).astype(np.int8)
    inf = np.inf
    cuts = [0.9 + 0.03 * k for k in range(comm.size - 1)]  # rank 0: x < 0.9; the others: slabs beyond
    splits = tuple(Split(k, comm.size, k + 1, 0, c) for k, c in enumerate(cuts))
    edges = [-inf, *cuts, inf]
    boxes = tuple((np.array([edges[r], -inf]), np.array([edges[r + 1], inf])) for r in range(comm.size))

    def shifted(on, operator):
        mine = on.rank == 0
        p = ParticleSet(2)
        p.set_owned({"gid": np.arange(len(lattice)) if mine else np.zeros(0, np.int64),
                     "position": lattice.copy() if mine else np.zeros((0, 2)),
                     "kind": kind if mine else np.zeros(0, np.int8),
                     "volume": np.full(len(lattice) if mine else 0, (0.3 / n) ** 2)})
        system = ParticleSystem(on, Domain((0.0, 0.0), (1.0, 1.0), (False, False)),
                                make_kernel("wendland_c6", 2, 2 * 0.3 / n), p, rebalance_threshold=1e30,
                                decomposition=Decomposition(splits, boxes) if on.size > 1 else None)
        with petsc_options(iips_ksp_rtol=1e-13, iips_ksp_atol=1e-30):
            spec = periodic_scene(n=20, iips={"max_newton": 3, "operator": operator}).iips
            report = ImplicitShifting(spec, on).correct(system)
        owned = on.allgather(system.particles.n_owned)
        return report, gather_by_gid(on, system.particles.owned("gid"), system.particles.owned("position"))[1], owned

    report, pos, owned = shifted(comm, operator)
    serial_report, serial_pos, _ = shifted(MPI.COMM_SELF, "assembled")
    assert comm.size == 1 or owned[1:] == [0] * (comm.size - 1)
    assert report.iterations == 3 and np.isfinite(report.L2_grad_c)
    assert report.L2_grad_c == pytest.approx(serial_report.L2_grad_c, rel=1e-8)
    assert np.abs(pos - serial_pos).max() < 1e-10


@pytest.mark.parametrize("mat_type,in_place", [("aij", True), ("baij", True), ("aij", False), ("baij", False)])
def test_assembled_petsc_matrix_is_the_printed_operator(comm, mat_type, in_place, monkeypatch):
    """The distributed matrix (values written into PETSc's AIJ / BAIJ arrays, or, where PETSc's split
    blocks are not as expected, through setValues(Blocked)CSR) equals the dense printed operator, row by
    row, compared through gids."""
    from tests.compute.test_iips import printed_operator

    if not in_place:  # the fallback: on several ranks the split blocks "disagree"
        monkeypatch.setattr("psph.solvers.aij.split_positions", lambda *args: False)
    scene = periodic_scene(n=10, sigma=0.2, h_over_dx=1.6, iips={"max_newton": 1})
    with petsc_options(iips_mat_type=mat_type):
        shifting = ImplicitShifting(scene.iips, comm)
        system = build_system(scene, comm)
        shifting.assemble(system)
    assert shifting.mat.getType().endswith(mat_type)
    # values written into PETSc's arrays, or through setValuesCSR (the seq path never splits)
    assert bool(shifting.operator.matrix.blocks) == (in_place or comm.size == 1)
    p = system.particles
    free = p.owned("kind") == 0
    rows = np.concatenate(comm.allgather(p.owned("row")[free]))
    gids = np.concatenate(comm.allgather(p.owned("gid")[free]))
    gid_of_row = np.empty(len(rows), np.int64)
    gid_of_row[rows] = gids
    _, pos = gather_by_gid(comm, p.owned("gid"), p.owned("position"))
    expect = printed_operator(pos, np.full(len(pos), 0.01), np.ones(len(pos), bool), system.kernel, system.domain)
    r0, r1 = shifting.mat.getOwnershipRange()
    for r in range(r0, r1):
        cols, vals = shifting.mat.getRow(r)
        g_row, comp = gid_of_row[r // 2], r % 2
        dense_row = np.zeros(expect.shape[1])
        dense_row[2 * gid_of_row[cols // 2] + cols % 2] = vals
        assert np.allclose(dense_row, expect[2 * g_row + comp], rtol=0, atol=1e-12 * np.abs(expect).max())
