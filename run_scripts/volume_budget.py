"""Where the total volume of a walled delta-ALE-SPH flow comes from: the budget of d(sum_i V_i)/dt.

    .venv/bin/python run_scripts/volume_budget.py [--walls clone ghost] [--dx 0.04] [--t0 2] [--t1 6]
        [--set physics.reynolds=1000 --set shifting.method=iips --set iips.update=nfts] [--out DIR]
        [PETSc options, e.g. -iips_ksp_rtol 1e-3]

Both wall models run with delta+ shifting (seed 001's; the cavity scene's own is IIPS + NFTS) unless --set
says otherwise. With V_i = m_i / rho_i (seed 001 eq. 13), dV_i/dt = V_i (dm_i/dt / m_i - drho_i/dt / rho_i).
After every time step the right-hand side is split into the fluid pairs' and the walls' parts, each with and
without its shifting (du) terms, summed over regions of the lid-driven cavity (the two top corners, the rest
of the lid, the other walls, the interior), and integrated over t0..t1 (one evaluation per step, at its end).
For the fluid pairs, the du terms of the continuity equation (eq. 12: div du as a difference, div(rho du) as a
sum) add up over all particles to -2 sum_i V_i du_i . grad C_i (grad C over the fluid pairs), and with clone
walls, whose du mirrors the particle's own, to the same with the walls' part of grad C included: printed as
"-2 V du.grad C" to check. With IIPS (no du terms) the field update after each IIPS call is a part of its own,
measured as the change of each particle's volume over the call (NFTS sweeps volume with its fictitious time
step; seed 000 eq. 9.7), by region of the particle's final position. Writes
results/volume_budget/budget.{md,csv}.
"""

import argparse
import sys
from contextlib import contextmanager, nullcontext
from pathlib import Path

import numpy as np
from mpi4py import MPI

from psph.compute.fluid import delta_ale_rhs
from psph.diagnostics import fluid_mask, grad_c
from psph.drivers.fluid import FluidDriver
from psph.errors import PsphError
from psph.parallel.comm import allreduce_sum
from psph.particles import FieldSpec
from psph.scene.load import load_scene
from psph.simulation import check_resources
from psph.solvers.petsc import initialize
from psph.studies import (
    CAVITY,
    CAVITY_DELTA_PLUS,
    CAVITY_WALLS,
    command_line,
    parse_args,
    positive_float,
    stamp_out,
    write_table,
)

PARTS = ("fluid pairs, u", "fluid pairs, du", "walls, u", "walls, du", "IIPS field update")
REGIONS = ("top-left corner", "top-right corner", "lid", "other walls", "interior")
UPDATE, CHECK = len(PARTS) - 1, len(PARTS)  # table rows: the field update's part, -2 V du.grad C


@contextmanager
def shifting_off(scheme):
    """The scheme's right-hand side pieces without their du terms (the shift law is left as it is)."""
    active = scheme.shift.active
    scheme.shift.active = False
    try:
        yield
    finally:
        scheme.shift.active = active


def regions(x, support):
    """Masks of REGIONS for positions x in the unit cavity."""
    top = x[:, 1] > 1.0 - 2.0 * support
    left, right = top & (x[:, 0] < 2.0 * support), top & (x[:, 0] > 1.0 - 2.0 * support)
    lid = (x[:, 1] > 1.0 - support) & ~left & ~right
    near = np.minimum.reduce([x[:, 0], 1.0 - x[:, 0], x[:, 1], 1.0 - x[:, 1]]) < support
    walls = near & ~left & ~right & ~lid
    return left, right, lid, walls, ~(left | right | lid | walls)


def rates(drv, t, dt):
    """Per fluid particle dV/dt of each part of PARTS, and -2 V du . grad C, at the current state."""
    sch, system = drv.scheme, drv.system
    p = system.particles
    full = sch.rhs(system, t, dt)  # refreshes the halo, the shift velocity, grad rho and the pair cache
    n, d = p.n_owned, p.dim
    du = p["shift_velocity"] if sch.shift.active else p["velocity"]  # IIPS: no du terms
    fluid = {}
    for shifted in (True, False):
        d_rho, d_mass = np.zeros(n), np.zeros(n)
        delta_ale_rhs(p["position"], p["volume"], p["density"], p["mass"], p["velocity"],
                      du if shifted else p["velocity"], p["pressure"], p["grad_rho"], sch.pairs,
                      system.kernel.params, sch.c0, sch.delta, sch.delta_m, sch.mu, sch.gravity, sch.variant,
                      shifted and sch.shift.active, sch.tensile, p["kind"], True, d_rho, d_mass, np.zeros((n, d)))
        fluid[shifted] = (d_rho, d_mass)
    walls = {}
    for shifted in (True, False):
        walls[shifted] = np.zeros(n)
        with nullcontext() if shifted else shifting_off(sch):
            sch.walls.add(system, sch, t, walls[shifted], np.zeros((n, d)))
    assert np.allclose(full["density"], fluid[True][0] + walls[True], rtol=1e-10, atol=1e-12)
    mask = fluid_mask(system)
    vol, m, rho = p.owned("volume"), p.owned("mass"), p.owned("density")

    def dv(d_rho, d_mass):
        return (vol * (d_mass / m - d_rho / rho))[mask]

    zero = np.zeros(n)
    out = [dv(*fluid[False]), dv(fluid[True][0] - fluid[False][0], fluid[True][1] - fluid[False][1]),
           dv(walls[False], zero), dv(walls[True] - walls[False], zero)]
    grad = grad_c(system, "volume")
    sch.walls.add_ghost_grad_c(system, 0.0, 1.0, 1.0, grad)
    out.append((-2.0 * vol * (du[:n] * grad).sum(axis=1))[mask] if sch.shift.active else np.zeros(mask.sum()))
    return out


def budget(scene, t0, t1, out_dir):
    """Integrated parts (fractions of the initial volume) per region over t0..t1, and eps_V at both ends."""
    with FluidDriver(scene, MPI.COMM_WORLD, out_dir) as drv:  # its solvers and communicators freed after
        system = drv.system
        p = system.particles
        v0 = drv.initial_volume
        table = np.zeros((len(PARTS) + 1, len(REGIONS)))
        update_after = drv.update.after

        p.add_field(FieldSpec("volume_before_update"))  # travels with its particle through rebuilds

        def measured_update(system, scheme):  # the IIPS field update's part, once eps_V(t0) is taken
            p.owned("volume_before_update")[:] = p.owned("volume")
            update_after(system, scheme)
            if eps:
                mask = fluid_mask(system)
                masks = regions(p.owned("position")[mask], system.kernel.support)
                change = (p.owned("volume") - p.owned("volume_before_update"))[mask]
                table[UPDATE] += [change[k].sum() / v0 for k in masks]

        drv.update.after = measured_update
        state = {"step": 0, "time": 0.0}
        totals = drv.new_totals()
        eps = []
        while state["time"] < t1 * (1.0 - 1e-12):
            dt, vmax = drv.time_step(state["time"])
            drv.first_dt = drv.first_dt or dt
            dt = min(dt, t1 - state["time"])
            drv.advance(state, dt, vmax, totals)
            mask = fluid_mask(system)
            if state["time"] < t0:
                continue
            if not eps:
                eps.append(total_volume(system) / v0 - 1.0)
            if state["time"] < t1 * (1.0 - 1e-12):
                masks = regions(p.owned("position")[mask], system.kernel.support)
                for a, r in zip((0, 1, 2, 3, CHECK), rates(drv, state["time"], dt)):
                    table[a] += [dt * r[k].sum() / v0 for k in masks]
        eps.append(total_volume(system) / v0 - 1.0)
        return allreduce_sum(system.comm, table), eps


def total_volume(system):
    """Sum of the fluid particles' volumes over all ranks. Collective."""
    return allreduce_sum(system.comm, float(system.particles.owned("volume")[fluid_mask(system)].sum()))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--walls", nargs="+", default=["clone", "ghost"], choices=["clone", "ghost"])
    parser.add_argument("--dx", type=positive_float, default=0.04)
    parser.add_argument("--t0", type=float, default=2.0)
    parser.add_argument("--t1", type=float, default=6.0)
    parser.add_argument("--out", type=Path, default=Path("results/volume_budget"))
    args = parse_args(parser)  # --set KEY=VALUE for every run (e.g. physics.reynolds=1000), and PETSc options
    if args.petsc:  # before the first PETSc object (a process that has made one keeps its options)
        initialize(args.petsc)
    scenes = {}
    for walls in args.walls:  # every scene is checked before the first run starts
        try:
            scenes[walls] = load_scene(CAVITY, [f"domain.dx={args.dx}", f"time.t_end={args.t1}", "output.every=0",
                                                 *CAVITY_DELTA_PLUS, *CAVITY_WALLS[walls], *args.set])
            check_resources(scenes[walls], allow_large=args.allow_large, ranks=MPI.COMM_WORLD.size)  # as psph run
        except PsphError as err:
            parser.error(f"{walls} walls: {err}")
    rows = []
    args.out.mkdir(parents=True, exist_ok=True)
    stamp_out()  # (it runs psph in-process: --out is this study's from here on)
    for walls, scene in scenes.items():
        try:
            table, eps = budget(scene, args.t0, args.t1, args.out / f"run_{walls}")
        except PsphError as err:  # a bad PETSc option, a numerical failure: one line, the earlier runs' files kept
            sys.exit(f"volume_budget.py: {walls} walls: {err}")
        for name, values in zip(PARTS + ("-2 V du.grad C",), table):
            rows.append([walls, name, *values, values.sum()])
        rows.append([walls, "sum of the parts", *table[:-1].sum(axis=0), table[:-1].sum()])
        rows.append([walls, f"eps_V({args.t1:g}) - eps_V({args.t0:g})", *[float("nan")] * len(REGIONS),
                     eps[1] - eps[0]])
        if MPI.COMM_WORLD.rank == 0:
            print(f"{walls}: eps_V {eps[0]:.4e} -> {eps[1]:.4e}", flush=True)
    if MPI.COMM_WORLD.rank:
        return
    print(write_table(args.out / "budget", ["walls", "part", *REGIONS, "total"], rows,
                      title=f"Lid-driven cavity, Re = {scene.physics.reynolds:g}, dx = {args.dx:g}"
                            f"{''.join(', ' + s for s in args.set if not s.startswith('physics.reynolds='))}: volume "
                            f"budget over t = {args.t0:g}..{args.t1:g} (fractions of the initial volume)",
                      note="One right-hand side evaluation per step, at its end (a left Riemann sum of the rate). "
                           "Command: " + command_line()))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
