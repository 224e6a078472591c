"""Particle right-hand-side evaluations per second per core for the delta-ALE-SPH scheme (2-D periodic
Taylor-Green, Wendland C6, h = 2 dx: ~45 neighbours in the support, 60 in the lists with the 10% skin).

    .venv/bin/python run_scripts/bench_flow.py [--sizes 100 200] [--shifting none delta_plus]
                                               [--scheme riemann_ale]
    mpiexec -n 2 .venv/bin/python run_scripts/bench_flow.py      # per rank on 2 ranks

One evaluation = everything a Runge-Kutta stage does for the scheme: equation of state, halo refresh of the
fields, the shifting velocity (if any), the renormalised density gradient, and the fused right-hand side.
Reference: TrixiParticles reports ~1 M particle-RHS/s per core for a 2-D WCSPH right-hand side with ~37
neighbours (C2); psph aims for 0.7 M with C6. Each evaluation is timed on its own; the script prints the
median and the best rate (the best is what the code does on an undisturbed core: on a shared virtual
machine the median can drift by 30% between runs), each the minimum over ranks.
"""

import argparse
import time

import numpy as np
from mpi4py import MPI

from psph import profiling
from psph.cli import positive_float, positive_int
from psph.scene.load import scene_from_table
from psph.scene.schema import EXPLICIT_LAWS, FLUID_SCHEMES
from psph.schemes import make_scheme
from psph.simulation import build_system
from psph.studies import check_scene_memory, parse_plain


def diffusion(scheme, delta) -> dict:
    """The scheme's diffusive coefficients at delta (delta_ale's D^rho and D^m; its variants' D^rho)."""
    keys = {"riemann_ale": (), "delta_ale": ("delta", "delta_m")}.get(scheme, ("delta",))
    return {key: delta for key in keys}


def flow_scene(n, scheme, method, delta):
    """The benchmark's scene: n x n particles of the bi-periodic unit box, a perturbed Taylor-Green vortex."""
    return scene_from_table({
        "name": "bench", "domain": {"dimension": 2, "lower": [0.0, 0.0], "upper": [1.0, 1.0],
                                    "periodic": [True, True], "dx": 1.0 / n},
        "initial": {"velocity": "taylor_green", "sigma_over_dx": 0.1},
        "physics": {"scheme": scheme, **diffusion(scheme, delta)},
        "time": {"t_end": 1.0}, "shifting": {"method": method}})


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=positive_int, nargs="+", default=[100, 200], help="particles per side")
    parser.add_argument("--shifting", nargs="+", default=["none", "delta_plus"], choices=["none", *EXPLICIT_LAWS],
                        help="an explicit law (IIPS shifts between steps, outside the right-hand side: "
                             "bench_iips.py)")
    parser.add_argument("--seconds", type=positive_float, default=4.0, help="minimum timed wall time per case")
    parser.add_argument("--scheme", default="delta_ale", choices=FLUID_SCHEMES)
    parser.add_argument("--delta", type=float, nargs="+", default=[0.1],
                        help="physics.delta (and delta_m): 0 is standard SPH, whose diffusive terms cost nothing "
                             "(not read by riemann_ale)")
    args = parse_plain(parser)
    comm = MPI.COMM_WORLD
    for n in args.sizes:  # build_system allocates without psph run's check
        check_scene_memory(parser, "--sizes", n, flow_scene(n, args.scheme, "none", max(args.delta)), comm.size)
    if comm.rank == 0:
        print(f"{args.scheme} right-hand side, {comm.size} rank(s), Wendland C6, h = 2 dx")
        print(f"{'particles':>10} {'shifting':>11} {'delta':>6} {'RHS/s per core [M]: median':>27} {'best':>6}"
              "  split (rank 0)")
    for n in args.sizes:
        for method, delta in ((m, dl) for m in args.shifting for dl in args.delta):
            scene = flow_scene(n, args.scheme, method, delta)
            scheme = make_scheme(scene)
            system = build_system(scene, comm, specs=scheme.field_specs(), halo_fields=scheme.halo_fields())
            scheme.initialize(system)
            state = scheme.state(system)
            scheme.set_state(system, state)
            scheme.rhs(system, 0.0, 1e-4)  # warm up
            profiling.reset()
            times = []
            comm.Barrier()
            t0 = time.perf_counter()
            while True:
                start = time.perf_counter()
                scheme.set_state(system, state)
                scheme.rhs(system, 0.0, 1e-4)
                times.append(time.perf_counter() - start)
                if comm.allreduce(time.perf_counter() - t0, op=MPI.MAX) >= args.seconds:
                    break
            elapsed = time.perf_counter() - t0
            median, best = (comm.allreduce(system.n_owned / t / 1e6, op=MPI.MIN)
                            for t in (np.median(times), min(times)))
            parts = profiling.totals()
            split = ", ".join(f"{k} {100 * v[0] / elapsed:.0f}%" for k, v in sorted(parts.items()))
            n_global = system.n_global  # collective
            if comm.rank == 0:
                print(f"{n_global:>10} {method:>11} {delta:>6g} {median:>27.3f} {best:>6.3f}  {split}")


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
