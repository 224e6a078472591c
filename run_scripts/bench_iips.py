"""Cost of one IIPS Newton iteration on 2-D perturbed lattices (40k and 160k particles, C6, h = 2 dx,
sigma/dx = 0.1), split into its parts, and the time per KSP iteration against the memory-bandwidth bound
of the matrix.

    .venv/bin/python run_scripts/bench_iips.py                  # one rank
    mpiexec -n 2 .venv/bin/python run_scripts/bench_iips.py     # two ranks (figures per rank)
    ... [PETSc options, e.g. -iips_pc_type hypre]

Bandwidth: a single-core STREAM triad (a = b + s c, numba, 3 x 8 bytes per element, best of 5) measured
in the same process. Bound of one BCGS + Jacobi iteration: two matrix-vector products and 27 vector sweeps
of 8 bytes per row (PETSc's event counts per iteration: 2 VecDot and 1 VecDotNorm2, 2 x 2 + 2 reads; 1
VecNorm, 1; 2 VecAXPBYPCZ, 2 x 4; 2 VecWAXPY, 2 x 3; 2 Jacobi VecPointwiseMult, 2 x 3; a benchmark
audit: the script counted 20). An AIJ product reads 8 bytes per nonzero and a 4-byte column index per
nonzero of each I-node (PETSc groups the d rows of a particle, whose columns are the same: 8 + 4 / d per
nonzero; BAIJ, one index per d x d block: 8 + 4 / d^2), and per row its row pointer (PetscInt), x and
the result (the script counted 12 bytes per nonzero). With `--operator matrix_free` (iips.operator) the
product reads per stored pair (a pair of the rank's own unknowns is stored once) its d (d + 1) / 2
Hessian entries and one 4-byte column (8 x 3 + 4 bytes in 2-D), per particle its row pointer (8 bytes),
and per scalar row copies x into the product's input, scales it by the volumes and writes the result (52
bytes). OpenBLAS, which PETSc's dot products and norms call, runs on one thread (OPENBLAS_NUM_THREADS = 1
unless set): its threads took 15-50% of the solve on a loaded machine, and the second core on an idle one.
"""

import argparse
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy and PETSc load OpenBLAS

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

from psph.cli import positive_int, split_petsc_options  # noqa: E402
from psph.studies import check_scene_memory, parse_plain  # noqa: E402

SWEEPS = 27  # vectors of 8 bytes per row read or written per BCGS + Jacobi iteration (docstring)


@njit(cache=True)
def triad(a, b, c, s):
    for i in range(a.size):
        a[i] = b[i] + s * c[i]


def stream_bandwidth(n=20_000_000):
    a, b, c = np.zeros(n), np.ones(n), np.ones(n)
    triad(a, b, c, 3.0)
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        triad(a, b, c, 3.0)
        best = min(best, time.perf_counter() - t0)
    return 24.0 * n / best


def iips_scene(n, operator):
    """The benchmark's scene: n x n particles of the bi-periodic unit box, sigma/dx = 0.1, one Newton iteration."""
    from psph.scene.load import scene_from_table

    return scene_from_table({"name": "bench", "domain": {
        "dimension": 2, "lower": [0.0, 0.0], "upper": [1.0, 1.0], "periodic": [True, True], "dx": 1.0 / n},
        "initial": {"sigma_over_dx": 0.1, "seed": 1}, "shifting": {"method": "iips"},
        "iips": {"max_newton": 1, "operator": operator}})


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=positive_int, nargs="+", default=[200, 400], help="particles per side")
    parser.add_argument("--iterations", type=positive_int, default=3,
                        help="timed Newton iterations (after two warm-up calls)")
    parser.add_argument("--operator", choices=["assembled", "matrix_free"], default="assembled",
                        help="iips.operator (default: the assembled AIJ matrix, whose bandwidth bound is printed; "
                             "a scene's default is matrix-free)")
    ours, petsc_args = split_petsc_options(sys.argv[1:])  # a mistyped --option is an error, not a PETSc option
    args = parse_plain(parser, ours)

    from psph.solvers.petsc import initialize

    initialize(petsc_args)
    from mpi4py import MPI

    from psph import profiling
    from psph.parallel.comm import allreduce_max
    from psph.shifting.iips import ImplicitShifting
    from psph.simulation import build_system
    from psph.solvers.petsc import petsc

    comm = MPI.COMM_WORLD
    for n in args.sizes:  # build_system allocates without psph run's check
        check_scene_memory(parser, "--sizes", n, iips_scene(n, args.operator), comm.size,
                           assembled=args.operator == "assembled")
    bandwidth = stream_bandwidth()
    bandwidth = comm.allreduce(bandwidth, op=MPI.MIN)
    if comm.rank == 0:
        print(f"IIPS Newton iteration cost, {comm.size} rank(s); STREAM triad bandwidth {bandwidth / 1e9:.2f} GB/s "
              f"per core (min over ranks)")
    # exclusive times: halo exchange and neighbour search inside a rebuild are theirs, not the rebuild's
    # (which keeps migration and sorting)
    parts = ["grad_c", "iips_structure", "iips_assemble", "ksp_solve", "halo_exchange", "neighbour_search",
             "rebuild"]
    for n in args.sizes:
        scene = iips_scene(n, args.operator)
        system = build_system(scene, comm)
        shifting = ImplicitShifting(scene.iips, comm)
        # warm-up: compiles and builds the matrix structure; the first call's step rebuilds the neighbour lists
        # at its end, whose structure the second builds (timed, it stood beside the rebuild's untimed search)
        shifting.correct(system)
        shifting.correct(system)
        profiling.reset()
        its = 0
        comm.Barrier()
        t0 = time.perf_counter()
        for _ in range(args.iterations):
            its += shifting.correct(system).linear_iterations
        total = (time.perf_counter() - t0) / args.iterations
        t = profiling.exclusive()
        split = {k: t.get(k, 0.0) / args.iterations for k in parts}
        rows = shifting.mat.getLocalSize()[0]
        ksp_its = its / args.iterations
        per_its = split["ksp_solve"] / max(ksp_its, 1)
        kind = shifting.mat.getType()
        d = system.particles.dim
        if kind == "python":  # matrix-free: this rank's stored pairs
            nnz = int(shifting.operator.bptr[-1])
            stored = "pairs"
            product = (8 * d * (d + 1) // 2 + 4) * nnz + 8 * rows // d + 52 * rows
        else:
            nnz = shifting.mat.getInfo(petsc().Mat.InfoType.LOCAL)["nz_used"]  # this rank's (the default sums)
            stored = "nonzeros"
            index = np.dtype(petsc().IntType).itemsize
            product = (8 + 4 / (d ** 2 if "baij" in kind else d)) * nnz + (index + 16) * rows
        bound = (2 * product + SWEEPS * 8 * rows) / bandwidth
        worst = {k: allreduce_max(comm, v) for k, v in split.items()}
        per_its_max = allreduce_max(comm, per_its)
        bound_max = allreduce_max(comm, bound)
        rest = total - sum(split.values())  # this rank's time outside the listed parts
        total = allreduce_max(comm, total)
        if comm.rank == 0:
            print(f"\n{n * n} particles ({rows} local rows, {nnz:.0f} local {stored} on rank 0, {kind})")
            print(f"  time per one-iteration call {1e3 * total:.1f} ms (max over ranks); parts:")
            for k in parts:
                name = "rebuild, rest" if k == "rebuild" else k
                print(f"    {name:16s} {1e3 * worst[k]:8.1f} ms  ({100 * worst[k] / total:4.1f} %)")
            print(f"    {'outside these':16s} {1e3 * rest:8.1f} ms  ({100 * rest / total:4.1f} %, rank 0)")
            print(f"  a Newton iteration inside a longer call, without the call's first grad C (half the grad_c "
                  f"above): {1e3 * (total - worst['grad_c'] / 2):.1f} ms")
            print(f"  KSP iterations per Newton iteration {ksp_its:.1f} ({shifting.solver.describe()})")
            print(f"  time per KSP iteration {1e3 * per_its_max:.2f} ms, bandwidth bound {1e3 * bound_max:.2f} ms "
                  f"-> {per_its_max / bound_max:.2f} x the bound")


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
