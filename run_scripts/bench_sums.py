"""Pair throughput of the grad C sum on 2-D periodic lattices (10k, 40k, 160k particles; C6, h = 2 dx).

    .venv/bin/python run_scripts/bench_sums.py [--sizes 100 200 400] [--min-time 0.3]   # one core
    mpiexec -n 2 .venv/bin/python run_scripts/bench_sums.py          # per rank on 2 ranks

Prints, per lattice, the pair evaluations per second per core of psph's sum (sorted particles, reused
CSR Verlet lists) counted two ways: pairs inside the kernel support (useful work, ~48 per particle) and
pairs in the list (support + skin), and, for comparison, a naive numba cell-list loop that searches the
cells at every evaluation; and the building of the neighbour lists themselves (compute.neighbours, owned
rows over owned and halo particles, list radius = support + skin), in list pairs written per second; and
the MLS-II field update (compute.field_update, 4 fields) in microseconds per particle. Times are the best of
several repetitions of at least --min-time seconds (0.3) each; a smaller one (`--sizes 10 --min-time 0.01`, the
smoke run of tests/test_run_scripts.py) prints the same figures, less steady.
"""

import argparse
import time

import numpy as np
from mpi4py import MPI
from numba import njit

from psph.cli import positive_float, positive_int
from psph.compute import sums
from psph.compute.field_update import mls_interpolate
from psph.compute.neighbours import build_cross_lists, build_neighbour_lists
from psph.compute.smoothing import kernel_f
from psph.scene.load import scene_from_table
from psph.simulation import build_system
from psph.studies import check_scene_memory, parse_plain


@njit(cache=True)
def naive_grad_c(pos, vol, kp, support, out, n_rows):
    """Baseline: bin into cells and loop over the 3x3 neighbouring cells at every call (no reuse), for the
    first n_rows rows (the owned ones, as psph's sum; it summed the halo rows too, 4-17% more rows than
    its rate counted: a benchmark audit)."""
    n = pos.shape[0]
    lo0, lo1 = pos[:, 0].min(), pos[:, 1].min()
    nc0 = int((pos[:, 0].max() - lo0) / support) + 1
    nc1 = int((pos[:, 1].max() - lo1) / support) + 1
    cell = np.empty(n, np.int64)
    for i in range(n):
        cell[i] = int((pos[i, 0] - lo0) / support) * nc1 + int((pos[i, 1] - lo1) / support)
    order = np.argsort(cell)
    start = np.searchsorted(cell[order], np.arange(nc0 * nc1 + 1))
    for i in range(n_rows):
        c0 = int((pos[i, 0] - lo0) / support)
        c1 = int((pos[i, 1] - lo1) / support)
        g0 = 0.0
        g1 = 0.0
        for a in range(max(c0 - 1, 0), min(c0 + 2, nc0)):
            for b in range(max(c1 - 1, 0), min(c1 + 2, nc1)):
                c = a * nc1 + b
                for m in range(start[c], start[c + 1]):
                    j = order[m]
                    if j == i:
                        continue
                    d0 = pos[i, 0] - pos[j, 0]
                    d1 = pos[i, 1] - pos[j, 1]
                    r = np.sqrt(d0 * d0 + d1 * d1)
                    if r < support:
                        s = kernel_f(r, kp) * vol[j]
                        g0 += s * d0
                        g1 += s * d1
        out[i, 0] = g0
        out[i, 1] = g1


def best_time(fn, min_time=0.3, repeats=5):
    fn()  # compile / warm up
    best = np.inf
    for _ in range(repeats):
        count, t0 = 0, time.perf_counter()
        while True:
            fn()
            count += 1
            elapsed = time.perf_counter() - t0
            if elapsed >= min_time:
                break
        best = min(best, elapsed / count)
    return best


def lattice_scene(n):
    return scene_from_table({"name": "bench", "domain": {
        "dimension": 2, "lower": [0.0, 0.0], "upper": [1.0, 1.0], "periodic": [True, True], "dx": 1.0 / n,
        "h_over_dx": 2.0, "kernel": "wendland_c6"}})


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=positive_int, nargs="+", default=[100, 200, 400], help="particles per side")
    parser.add_argument("--min-time", type=positive_float, default=0.3,
                        help="minimum wall time of each timed repetition, in seconds (default 0.3)")
    args = parse_plain(parser)
    comm = MPI.COMM_WORLD
    for n in args.sizes:  # build_system allocates without psph run's check
        check_scene_memory(parser, "--sizes", n, lattice_scene(n), comm.size)
    if comm.rank == 0:
        print(f"grad C pair throughput, {comm.size} rank(s), Wendland C6, h = 2 dx, 2-D periodic lattice")
        print(f"{'particles':>10} {'nbrs/ptcl':>9} {'useful Mpairs/s/core':>21} {'list Mpairs/s/core':>19} "
              f"{'naive Mpairs/s/core':>20} {'list build ms':>13} {'build Mpairs/s':>14} {'MLS-II us/ptcl':>14}")
    for n in args.sizes:
        system = build_system(lattice_scene(n), comm)
        p, k = system.particles, system.kernel
        pos, vol, ptr, idx = p["position"], p["volume"], system.nbr_ptr, system.nbr_idx
        out = np.zeros((p.n_owned, 2))
        rows = np.repeat(np.arange(p.n_owned), np.diff(ptr))
        useful = int(np.count_nonzero(np.linalg.norm(pos[rows] - pos[idx], axis=1) < k.support))
        t = best_time(lambda: sums.grad_concentration(pos, vol, ptr, idx, k.params, out), args.min_time)  # noqa: B023
        naive_out = np.zeros((p.n_owned, 2))
        t_naive = best_time(lambda: naive_grad_c(pos, vol, k.params, k.support, naive_out, p.n_owned),  # noqa: B023
                            args.min_time)
        assert np.allclose(naive_out[: p.n_owned], out, atol=1e-9 * np.abs(out).max() + 1e-12)
        t_build = best_time(lambda: build_neighbour_lists(pos, p.n_owned, system.list_radius), args.min_time)  # noqa: B023
        # the MLS-II field update of 2 + d fields at positions moved by 0.1 dx (shifting.field_update)
        moved = pos[: p.n_owned] + 0.1 / n
        near_ptr, near_idx = build_cross_lists(moved, pos, k.support)
        fields, fitted = np.ones((p.n_local, 4)), np.zeros((p.n_owned, 4))
        t_mls = best_time(lambda: mls_interpolate(moved, pos, vol, fields, near_ptr, near_idx, k.params, 2,  # noqa: B023
                                                  fitted), args.min_time)  # noqa: B023
        rates = np.array([useful / t, len(idx) / t, useful / t_naive, len(idx) / t_build]) / 1e6
        t_mls = comm.allreduce(t_mls / p.n_owned, op=MPI.MAX)
        worst = np.empty(4)
        comm.Allreduce(rates, worst, op=MPI.MIN)
        total = comm.allreduce(useful)
        t_build = comm.allreduce(t_build, op=MPI.MAX)
        if comm.rank == 0:
            label = "min over ranks" if comm.size > 1 else ""
            print(f"{n * n:>10} {total / (n * n):>9.1f} {worst[0]:>21.1f} {worst[1]:>19.1f} {worst[2]:>20.1f} "
                  f"{1e3 * t_build:>13.2f} {worst[3]:>14.1f} {1e6 * t_mls:>14.2f} {label}")


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
