"""physics.scheme = "kinematic": particles advected by a frozen analytic velocity field while a shifting
method keeps their distribution regular (thesis 000 section 8.3.2, Algorithms 2-4).

Each step: one shifting call (IIPS Procedure A or B; explicit shifting = Procedure C), then the
displacement of thesis eq. 8.33, dx_i = u(x_i) dt with the Taylor-Green field at t = 0 (explicit
Euler), dt = cfl dx / c0, the last step shortened to end at t_end. An explicit law of a fluid scheme
(shifting.method = delta_plus, lind, skillen, oger, neuhauser: psph.shifting.velocity) shifts instead
through the transport velocity, dx_i = (u(x_i) + du_i) dt, du from the law with the frozen field as the
fluid's velocity: thesis ch. 7's runs with "the initial analytical solution imposed during the entire
simulation" (figs. 7.1, 7.4); the volumes stay dx^d, so the fictitious pressure is refused. Before the
first step the shifting's static pre-procedure runs (`iips.pre_newton`). history.csv: one row every
`output.history_every` steps with Linf/L2(grad C) and L2(d f/dx) after the shifting (Algorithms 2-3, line
9), at the time the shifting was applied (the step's start: the step's advection follows; an explicit
law's shifting is part of the advection), Newton and KSP iterations, and cumulative shifting and step
times; summary.json's final values are the last row's (with its time), while the last snapshot holds the
state after the last advection, at t_end.
"""

import math
import time

import numpy as np

from psph.analytic import taylor_green
from psph.boundaries.clone import NO_WALLS
from psph.diagnostics import distribution_report, grad_c
from psph.drivers.base import Driver, resumed_state
from psph.errors import NumericalError
from psph.parallel.comm import allreduce_max
from psph.particles import FieldSpec
from psph.profiling import phase
from psph.shifting import make_shifting
from psph.shifting.base import steepest
from psph.shifting.iips import pre_procedure
from psph.shifting.velocity import make_velocity_shift, strength_key
from psph.simulation import Simulation
from psph.stop import checkpoint_message


def step_count(t_end, dt) -> int:
    """Steps of dt to reach t_end, the last one shortened (a step shorter than 1e-9 dt is not taken)."""
    return max(1, math.ceil(t_end / dt - 1e-9))


class KinematicDriver(Driver):
    walls = NO_WALLS  # what an explicit law reads of the scheme it shifts in (shift_by_law): a bi-periodic box

    @staticmethod
    def describe(scene) -> list:
        p, t = scene.physics, scene.time
        dt = t.cfl * scene.domain.dx / p.sound_speed
        n_steps = step_count(t.t_end, dt)
        last = t.t_end - (n_steps - 1) * dt
        return [f"physics kinematic: frozen {p.velocity_field} field (thesis eq. 8.33), U = {p.reference_velocity:g}, "
                f"explicit Euler, dt = {t.cfl:g} dx / c0 = {dt:.4g}, {n_steps} steps to t = {t.t_end:g}"
                + (f" (the last of {last:.4g})" if abs(last - dt) > 1e-9 * dt else ""),
                f"diagnostics: Linf/L2(grad C), L2(d f/dx) (wavelength {scene.diagnostics.test_wavelength:g})"
                ] + ([f"{law.describe()}; transport velocity u + du"] if (law := make_velocity_shift(scene)).active
                     else [])

    def __init__(self, scene, comm, out_dir, log=None, progress=False, restart=None):
        """restart: io.checkpoint.read_checkpoint's (state, particles, decomposition), to continue a run."""
        self.scene = scene
        self.law = make_velocity_shift(scene)  # an explicit law's; inactive for iips, explicit_iterative, none
        specs = ()
        if self.law.active:
            specs = (FieldSpec("velocity", ("d",)), *self.law.fields)
        self.sim = Simulation(scene, comm, out_dir, specs=specs, log=log, progress=progress, restart=restart)
        with self.closing_on_failure():
            self.shifting = make_shifting(scene, self.sim.comm)
            self.resumed = resumed_state(restart, scene)
            if self.resumed and self.resumed["shifting"] is not None:
                self.shifting.restore(self.resumed["shifting"])
        d, p = scene.domain, scene.physics
        self.dt = scene.time.cfl * d.dx / p.sound_speed
        # the steps count from here: the start, or a checkpoint whose time is not its step's at this dt (a
        # restart that changes time.cfl: counted from step 0, the run went back in time, an audit found)
        self.origin = (0, 0.0)
        if self.resumed and self.resumed["time"] != self.resumed["step"] * self.dt:
            self.origin = (self.resumed["step"], self.resumed["time"])
        self.n_steps = self.origin[0] + step_count(scene.time.t_end - self.origin[1], self.dt)
        self.length = d.upper[0] - d.lower[0]

    def step_time(self, step) -> float:
        """The time at the end of step `step` (1-based): dt on from the origin, the last step's end t_end."""
        first, t0 = self.origin
        return self.scene.time.t_end if step >= self.n_steps else t0 + (step - first) * self.dt

    def frozen_field(self, pos):
        """The frozen field's velocity at `pos` (thesis eq. 8.33: Taylor-Green at t = 0)."""
        return taylor_green(pos, 0.0, U=self.scene.physics.reference_velocity, L=self.length,
                            lower=self.scene.domain.lower)[0]

    def advect(self, dt):
        """Move the owned particles over dt by the frozen field (thesis eq. 8.33), plus an explicit law's
        shifting velocity (shift_by_law), and refresh. Collective."""
        system = self.sim.system
        p = system.particles
        pos = p.owned("position")
        self.law.end_step(system, self, dt)  # Neuhauser's memory: this step's transport velocity
        pos += dt * self.law.transport(p, velocity=self.frozen_field(pos))
        system.update()

    def shift_by_law(self, dt) -> None:
        """An explicit law's shifting velocity du for the step of dt about to be taken (owned rows of
        shift_velocity), the frozen field's velocity at the particles standing for the fluid's. Collective."""
        system = self.sim.system
        p = system.particles
        p.owned("velocity")[:] = self.frozen_field(p.owned("position"))
        system.refresh(["velocity"])
        self.law.velocity(system, self, dt)
        self.check_law_speed(dt)

    def check_law_speed(self, dt) -> None:
        """Stop every rank, naming the step, the particle and the law's strength key, where the law's shifting
        velocity exceeds the speed of sound c0 (a failure audit: skillen_a = 1e6 threw the particles 8-10 dx
        a step, at random through the box, and the run ended with exit 0; a fluid run stops on a particle
        faster than sound). Collective."""
        system, c0 = self.sim.system, self.scene.physics.sound_speed
        du = system.particles.owned("shift_velocity")
        fastest = allreduce_max(system.comm, float(np.nan_to_num(np.linalg.norm(du, axis=1), nan=np.inf).max(
            initial=0.0)))
        if fastest > c0:
            key = strength_key(self.scene.shifting)
            error = NumericalError(f"the explicit shifting law's velocity reached {fastest:.3g}, {fastest / c0:.3g} "
                                   f"times the speed of sound c0 = {c0:g} ({fastest * dt / self.scene.domain.dx:.2g} "
                                   f"dx in a step): the law is too strong"
                                   + (f" ({key})" if key else ""),
                                   **system.where, **steepest(system, du, np.arange(len(du))))
            error.collective = True  # (every rank has the maximum)
            raise error

    def start(self, totals) -> dict:
        """Pre-procedure, the history's first row and the first snapshot; returns the distribution report."""
        sim, system = self.sim, self.sim.system
        t0 = time.perf_counter()
        init_linf, iterations = pre_procedure(self.scene.iips, sim.comm, system,
                                              self.shifting if self.scene.shifting.method == "iips" else None)
        self.pre = {"time_s": time.perf_counter() - t0, "linf": init_linf}
        if init_linf is not None:
            threshold = getattr(self.shifting, "threshold", None)
            sim.log(f"pre-procedure: {iterations} IIPS iterations, Linf(grad C) = {init_linf:.4e}"
                    + (f", threshold {threshold:.4e}" if threshold else ""))
        if "transport_velocity" in system.particles:  # Neuhauser's v0 of the step before the first
            p = system.particles
            p.owned("transport_velocity")[:] = self.frozen_field(p.owned("position"))
        report = distribution_report(system, self.scene.diagnostics.test_wavelength)
        sim.history.append({"time": 0.0, "step": 0, **report, "newton": 0, "ksp_iterations": 0, **totals})
        sim.snapshots.write(system.particles, step=0, time=0.0, extra={"grad_c": grad_c(system)})
        return report

    def checkpoint(self, step, t, totals, next_output, report):
        shifting = getattr(self.shifting, "checkpoint_state", None)
        return self.sim.checkpoint(step, t, {"step": step, "time": t, "totals": totals, "next_output": next_output,
                                             "report": report, "report_time": self.report_time, "pre": self.pre,
                                             "shifting": shifting() if shifting else None})

    def run(self) -> dict:
        sim, scene = self.sim, self.scene
        system = sim.system
        wavelength = scene.diagnostics.test_wavelength
        totals = {"shifting_time_s": 0.0, "step_time_s": 0.0, "newton_iterations": 0, "linear_iterations": 0,
                  "failed_calls": 0, "rejected_calls": 0}
        state = {"step": 0, "time": 0.0}
        with sim.diagnose_failures(lambda: (state["step"], state["time"])):
            every = scene.output.every
            next_output = every if every > 0 else math.inf
            if self.resumed:
                state = {"step": self.resumed["step"], "time": self.resumed["time"]}
                totals.update(self.resumed["totals"])
                next_output = self.resumed["next_output"]
                report = self.resumed["report"]
                self.report_time = self.resumed.get("report_time", state["time"])
                self.pre = self.resumed["pre"]
                sim.log(f"psph: continuing from step {state['step']}, t = {state['time']:.6g}")
            else:
                report = self.start(totals)
                self.report_time = 0.0
            sim.settle()
            progress = sim.progress(state["time"], scene.time.t_end)
            last_checkpoint = time.monotonic()
            for step in range(state["step"] + 1, self.n_steps + 1):
                state["step"] = step
                system.where = {"step": step, "time": state["time"]}
                start = time.perf_counter()
                t = self.step_time(step)
                with phase("shifting"):
                    shift = self.shifting.correct(system, step=step, time=state["time"])
                    if self.law.active:
                        self.shift_by_law(t - state["time"])
                shift_time = time.perf_counter() - start
                if shift.failed:
                    totals["failed_calls"] += 1
                    totals["rejected_calls"] += int(shift.rejected)
                    sim.log(f"step {step}, t = {state['time']:.4g}: {shift.message}")
                record = step % scene.output.history_every == 0 or step == self.n_steps
                if record:  # the shifted distribution, before this step's advection
                    report, self.report_time = distribution_report(system, wavelength), state["time"]
                with phase("advect"):
                    self.advect(t - state["time"])
                state["time"] = t
                totals["shifting_time_s"] += shift_time
                totals["step_time_s"] += time.perf_counter() - start
                totals["newton_iterations"] += shift.iterations
                totals["linear_iterations"] += shift.linear_iterations
                if record:
                    sim.history.append({"time": self.report_time, "step": step, **report, "newton": shift.iterations,
                                        "ksp_iterations": shift.linear_iterations, **totals})
                progress.update(step, t, self.dt, newton=totals["newton_iterations"],
                                ksp=totals["linear_iterations"])
                if t >= next_output - 1e-12 * self.dt:
                    sim.history.flush()
                    sim.snapshots.write(system.particles, step=step, time=t, extra={"grad_c": grad_c(system)})
                    next_output += every
                written = None  # this step's checkpoint, if one was due
                if step < self.n_steps and sim.checkpoint_due(step, last_checkpoint):
                    written = self.checkpoint(step, t, totals, next_output, report)
                    last_checkpoint = time.monotonic()
                if step < self.n_steps and sim.stop_requested():
                    progress.close()
                    written = written or self.checkpoint(step, t, totals, next_output, report)
                    # after the checkpoint: a continuation writes its next snapshot over this one
                    sim.stop(checkpoint_message(step, t, written, sim.comm.size,
                                                sim.snapshot_once(step, t, lambda: {"grad_c": grad_c(system)})))
            progress.close()
        step, t = state["step"], state["time"]
        sim.history.flush()
        sim.snapshot_once(step, t, lambda: {"grad_c": grad_c(system)})
        sim.log(f"t = {t:.4g} after {step} steps; after the last shifting (t = {self.report_time:.4g}): Linf(grad C) "
                f"= {report['Linf_grad_c']:.4e}, L2(df/dx) = {report['L2_dfdx']:.4e}")
        return sim.summary(steps=step, final={**report, "time": self.report_time}, end_time=t,
                           pre_procedure_time_s=self.pre["time_s"],
                           pre_procedure_linf=self.pre["linf"], threshold=getattr(self.shifting, "threshold", None),
                           dt=self.dt, **totals)
