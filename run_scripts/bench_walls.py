"""Cost of the clone-particle walls as a fraction of the flow step (issue: walls and bodies, "Speed").

    .venv/bin/python run_scripts/bench_walls.py [--steps 200] [--cases lid_driven_cavity moving_square inclined_ellipse]
                                                [--set domain.h_over_dx=1.5]
    mpiexec -n 2 .venv/bin/python run_scripts/bench_walls.py      # per rank on 2 ranks

Runs each wall scene for a number of steps after a warm-up and prints the wall time of the `walls` phase
(solid placement and velocities per stage and at the step's end, their halo refresh, the nearest-node
search, the clone right-hand side of seed 004 eq. 5-9 and a container's reflection) against the whole
`fluid_step` phase, from psph's phase timers (the PETSc log events `psph:walls` and `psph:fluid_step`
under -log_view), per step the run took.
"""

import argparse
import tempfile
from pathlib import Path

from mpi4py import MPI

from psph import profiling
from psph.cli import positive_int
from psph.drivers.fluid import FluidDriver
from psph.scene.load import load_scene
from psph.studies import CASES, command_line, parse_plain, write_table

SETTINGS = {"lid_driven_cavity": ["domain.dx=0.02"], "moving_square": ["domain.dx=0.05"],
            "inclined_ellipse": ["domain.dx=0.04"]}  # a/dx = 25


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=positive_int, default=200)
    parser.add_argument("--cases", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    parser.add_argument("--shifting", default="delta_plus", help="shifting.method (iips adds its own cost)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="scene override")
    parser.add_argument("--out", type=Path, help="also write the table to OUT/walls_{N}ranks.md and .csv")
    args = parse_plain(parser)  # (--out checked before the runs)
    comm = MPI.COMM_WORLD
    rows = []
    for case in args.cases:
        sets = SETTINGS.get(case, []) + [f"shifting.method={args.shifting}", "output.every=0", "iips.update=none",
                                         *args.set]
        with tempfile.TemporaryDirectory() as out:
            out = comm.bcast(out, root=0)
            scene = load_scene(CASES / f"{case}.toml", sets + ["time.t_end=1.0"])  # only for its time step
            with FluidDriver(scene, comm, out) as driver:
                dt, _ = driver.time_step(0.0)
            short = load_scene(CASES / f"{case}.toml", sets + [f"time.t_end={10 * dt}"])
            with FluidDriver(short, comm, out) as warm_up:
                warm_up.run()
            profiling.reset()
            timed = load_scene(CASES / f"{case}.toml", sets + [f"time.t_end={args.steps * dt}"])
            with FluidDriver(timed, comm, out) as run:
                steps = run.run()["steps"]  # (t_end / dt steps by the first's dt: 1-6% more were taken)
            totals = profiling.totals()
            walls, step = totals.get("walls", (0.0, 0))[0], totals["fluid_step"][0]
            share = comm.allreduce(walls / step, op=MPI.MAX)
            if comm.rank == 0:
                print(f"{case}: {run.sim.n_particles} particles, {comm.size} rank(s), {steps} steps: walls "
                      f"{walls:.2f} s of the step's {step:.2f} s = {100 * share:.1f}% (max over ranks), "
                      f"{1e3 * step / steps:.1f} ms per step", flush=True)
                rows.append([case, run.sim.n_particles, comm.size, args.shifting, steps, walls, step,
                             100 * share, 1e3 * step / steps])
    if args.out is not None and comm.rank == 0:
        write_table(args.out / f"walls_{comm.size}ranks",
                    ["scene", "particles", "ranks", "shifting", "steps", "walls [s]", "flow step [s]",
                     "walls, % of the step (max over ranks)", "ms per step"], rows,
                    title=f"Cost of the clone-particle walls, {comm.size} rank(s)", note="Command: " + command_line())


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
