"""physics.scheme = delta_ale (or a variant): a flow integrated in time, with explicit shifting inside the
scheme or IIPS after each step (thesis 000 ch. 9: Procedure B, then the scene's field update).

Each step: dt from the CFL condition (thesis eq. 5.52, with each particle's sound speed) and the viscous
operator's stability limit (psph.schemes.viscous_limit); a neighbour rebuild if the step could outrun the
skin; the integrator's stages; the shifting law's end-of-step update;
the open boundaries' rows emitted, joined and removed (psph.boundaries.open); IIPS and its field update
when the scene asks; checks (NaN, density outside the weakly compressible range,
escaped particles, collapsing time step) that stop the run with the step, time, particle and a diagnostic
snapshot. history.csv every `output.history_every` steps: time, dt, kinetic energy (with gravity not along a
periodic axis, the potential energy -sum m g . x too), total mass and
momentum, total-volume error eps_V (seed 001 eq. 27), max |rho/rho0 - 1|, L2/Linf(grad C), the smallest
distance between two fluid particles over dx (`min_spacing`: pairing that grad C misses), IIPS work, and
against an analytic solution (Taylor-Green) L2|v_x - v_xA| (thesis eq. 3.8) and the kinetic-energy error.
"""

import math
import time

import numpy as np

from psph.analytic import taylor_green, taylor_green_kinetic_energy
from psph.boundaries.free_surface import make_free_surface
from psph.boundaries.open import describe_open, make_open_boundaries
from psph.compute.sums import nearest_distance
from psph.diagnostics import fluid_mask, grad_c, interpolate_fluid, norms
from psph.drivers.base import Driver, resumed_state
from psph.errors import NumericalError
from psph.initial import reset_initial_fields
from psph.io.history import start_series
from psph.parallel.comm import allreduce_max, allreduce_min, allreduce_sum, global_first, raise_if_any
from psph.particles import Kind
from psph.probes import NAME as PROBES_NAME
from psph.probes import Probes
from psph.profiling import phase
from psph.scene.schema import SKIN_MAX
from psph.schemes import make_scheme
from psph.schemes.integrators import INTEGRATORS, STAGE_REACH
from psph.schemes.viscous_limit import ViscousLimit
from psph.shifting.field_update import make_field_update
from psph.shifting.iips import pre_procedure
from psph.shifting.velocity import strength_advice
from psph.simulation import Simulation
from psph.stop import checkpoint_message
from psph.system import ListsExpired

DT_COLLAPSE = 1e-6  # a time step below this fraction of the first one is a breakdown
RECOVERY_STEPS = 10  # time.retries: steps without a failure before a halved time step doubles again
FAST_FLOW = 2.0  # FluidDriver.check_reference_velocity: transport speeds (u + du, du <= U / 2) above this x U


class TaylorGreenReference:
    """Errors against the analytic Taylor-Green vortex (analytic.taylor_green)."""

    def __init__(self, scene):
        d, ph = scene.domain, scene.physics
        side = d.upper[0] - d.lower[0]
        self.kw = dict(U=ph.reference_velocity, L=side, rho=ph.density,
                       reynolds=ph.reference_velocity * side / ph.kinematic_viscosity(d))
        self.lower = d.lower

    def errors(self, system, t, kinetic):
        """The L2 error of the velocity against the analytic vortex at t and the kinetic energy's. Collective."""
        p = system.particles
        mask = fluid_mask(system)
        vel, _ = taylor_green(p.owned("position"), t, lower=self.lower, **self.kw)
        err = (p.owned("velocity")[:, 0] - vel[:, 0])[mask]
        l2, _ = norms(system.comm, err, np.ones(len(err), bool))
        exact = taylor_green_kinetic_energy(t, **self.kw)
        # a vortex decayed to nothing (E_k underflows at Re ~ 1e-4) has no relative error
        return {"L2_vx_error": l2, "kinetic_energy_exact": exact,
                "kinetic_energy_error": float(kinetic) / exact - 1.0 if exact > 0.0 else math.nan}


class EllipticalDropReference:
    """The drop against its analytic evolution (analytic.EllipticalDrop, seed 002 section 3.4): semi-axes from
    the fluid's second moments about its centroid, a = 2 sqrt(sum V x^2 / sum V) (exact for a uniformly filled
    ellipse), their relative errors, and the RMS pressure error over the fluid in units of the initial
    centre pressure rho0 A0^2 R^2 / 2."""

    def __init__(self, scene):
        from psph.initial import elliptical_drop

        self.drop = elliptical_drop(scene, scene.time.t_end)
        self.p_scale = 0.5 * scene.physics.density * scene.physics.reference_velocity ** 2

    def errors(self, system, t, kinetic):
        """The drop's semi-axis and pressure errors against the analytic ellipse at t. Collective."""
        p, comm = system.particles, system.comm
        mask = fluid_mask(system)
        pos, vol = p.owned("position")[mask], p.owned("volume")[mask]
        first = allreduce_sum(comm, np.concatenate([[vol.sum()], vol @ pos]))
        rel = pos - first[1:] / first[0]
        second = allreduce_sum(comm, np.array([vol @ rel[:, 0] ** 2, vol @ rel[:, 1] ** 2]))
        a, b = 2.0 * np.sqrt(second / first[0])
        a_exact, b_exact, _, _ = self.drop.state(t)
        _, pressure = self.drop.fields(pos, t)
        l2, _ = norms(comm, (p.owned("pressure")[mask] - pressure) / self.p_scale, np.ones(len(pos), bool))
        return {"semi_axis_a": a, "semi_axis_b": b, "semi_axis_a_exact": a_exact, "semi_axis_b_exact": b_exact,
                "semi_axis_error": max(abs(a / a_exact - 1.0), abs(b / b_exact - 1.0)), "L2_pressure_error": l2}


class ImpingingJetReference:
    """A jet impinging normally on a plate against Taylor's wall solution (analytic.impinging_jet_wall; thesis
    eq. 3.3, diagnostics.impinging_jet), in units of the stagnation pressure rho0 U^2 / 2, at probes dx/2
    apart along the plate's top:
        load    the pressure the plate takes: the fluid particles' pressure forces on its solids (at the last
                right-hand side) spread along it by a hat of half-width 2 dx, -sum_i F_i,y hat(x_i - x_k); its
                integral is the plate's pressure force (a narrower hat samples the particles that sit still at
                the stagnation point: with dx, the time-averaged load there was 0.92 between 1.03 either side)
        fluid   the fluid's pressure there, Shepard-interpolated from the fluid particles (weighted towards
                the first row's, which a disordered wall layer raises: docs/results.md, "Impinging jet")
    Columns: the load at the stagnation point (`stagnation_pressure`, 1 exactly in the analytic solution),
    the fluid's there (`stagnation_pressure_fluid`) and the load's RMS error over |x - x0| <= 2 H
    (`wall_pressure_error`). The force on the plate (cl_pressure + cl_viscous with the plate's
    reference_length = 2 H) balances the jet's momentum flux at -2 in a steady state. Each history row also
    writes the whole load to OUT/wall_pressure.csv (time, then one column per probe, named by its x), for
    time averages over the acoustic ringing that the jet's impact leaves."""

    SPAN = 2.0  # half-width of the compared stretch of the plate, in jet half-widths H

    def __init__(self, scene, walls, out_dir=None, resumed_at=None):
        """walls: the scheme's boundaries.clone.WallTerms; out_dir: where wall_pressure.csv goes (None on every
        rank but one); resumed_at: a restart's time (the file keeps its rows up to it and continues), else
        the file starts afresh."""
        self.walls = walls
        jet, plate = scene.inflow[0], scene.bodies[0]
        self.H = 0.5 * (jet.upper[0] - jet.lower[0])
        self.U = abs(jet.velocity[1])
        self.x0 = 0.5 * (jet.upper[0] + jet.lower[0])
        self.wall = plate.center[1] + 0.5 * plate.size[1]
        self.rho = scene.physics.density
        x = self.x0 + np.arange(-2 * int(self.SPAN * self.H / scene.domain.dx), 2 * int(
            self.SPAN * self.H / scene.domain.dx) + 1) * 0.5 * scene.domain.dx
        self.probes = np.stack([x, np.full(len(x), self.wall)], axis=1)
        self.spread = 2.0 * scene.domain.dx  # the load's hat half-width
        self.centre = int(np.argmin(np.abs(x - self.x0)))
        self.path = None if out_dir is None else out_dir / "wall_pressure.csv"
        if self.path is not None:
            start_series(self.path, "time," + ",".join(f"x={v - self.x0:.6g}" for v in x), resumed_at)

    def wall_pressure(self, system) -> tuple:
        """(load, fluid) at the probes over rho0 U^2 / 2 (the fluid's nan where no fluid reaches; the load's
        before the first right-hand side, at t = 0). Collective."""
        scale, walls = 0.5 * self.rho * self.U ** 2, self.walls
        fluid = interpolate_fluid(system, system.particles.owned("pressure"), self.probes)
        s = np.abs(walls.particle_force_at[:, 0][None, :] - self.probes[:, 0][:, None]) / self.spread
        load = allreduce_sum(system.comm, -(np.maximum(1.0 - s, 0.0) / self.spread) @ walls.particle_force[:, 1])
        if not walls.measured:
            load[:] = np.nan
        return load / scale, fluid / scale

    def errors(self, system, t, kinetic):
        """The stagnation pressure against the analytic jet's. Collective."""
        from psph.analytic import impinging_jet_wall

        measured, fluid = self.wall_pressure(system)
        if self.path is not None:
            with open(self.path, "a") as f:
                f.write(f"{t!r}," + ",".join(f"{v:.8g}" for v in measured) + "\n")
        _, exact = impinging_jet_wall(self.probes[:, 0] - self.x0, H=self.H, U=self.U, rho=self.rho)
        err = measured - exact / (0.5 * self.rho * self.U ** 2)
        return {"stagnation_pressure": float(measured[self.centre]),
                "stagnation_pressure_fluid": float(fluid[self.centre]),
                "wall_pressure_error": float(np.sqrt(np.mean(err ** 2)))}


class DamBreakReference:
    """A dam break (seed 001 section 6.3, diagnostics.dam_break): the fluid column fills initial.fill_lower
    .. fill_upper against the tank's back wall (x = fill_lower[0]) and collapses along +x. Columns, in the
    units of the scene (H = the column's height, sqrt(g H) the velocity):
        front_x        the surge front, the largest x of a fluid particle, from the back wall (B - dx/2 at
                       t = 0, B the column's length); Ritter's dry-bed shallow-water front runs at 2 sqrt(g H),
                       the upper bound of the experiments' fronts
        column_height  the residual height at the back wall, the highest fluid particle within dx of it (H - dx/2
                       at t = 0)
    The potential energy (history column potential_energy, with any gravity) gives the energy budget."""

    def __init__(self, scene):
        lower = scene.initial.fill_lower or scene.domain.lower
        self.wall, self.bottom = lower[0], lower[1]
        self.dx = scene.domain.dx

    def errors(self, system, t, kinetic):
        """The surge front and the column height (the dam break's references). Collective."""
        pos = system.particles.owned("position")[fluid_mask(system)]
        back = pos[:, 0] < self.wall + self.dx
        front, height = allreduce_max(system.comm, np.array([
            pos[:, 0].max() - self.wall if len(pos) else -np.inf,
            pos[back, 1].max() - self.bottom if back.any() else -np.inf]))
        return {"front_x": float(front), "column_height": float(height)}


REFERENCES = {"taylor_green": TaylorGreenReference, "elliptical_drop": EllipticalDropReference}


def hold_step_advice(needed, skin, cfl) -> str:
    """What holds a time step that moved a particle `needed` x the kernel support (as a skin fraction: four
    times its displacement, which a stage half a step in caught) with the lists' skin fraction `skin`, at
    time.cfl = `cfl`: a larger neighbours.skin while one is allowed, else a shorter step."""
    shorter = f"a time step {skin / needed:.2g} times as long (time.cfl = {cfl:g} now)"
    if needed <= SKIN_MAX:
        return f"a neighbours.skin of {needed:.2g} would hold the step, as would {shorter}"
    return f"no neighbours.skin (at most {SKIN_MAX:g}) holds it: it needs {shorter} or shorter"


class FluidDriver(Driver):
    @staticmethod
    def describe(scene) -> list:
        scheme = make_scheme(scene)
        t = scene.time
        lines = scheme.describe()
        lines.append(f"time integration: {t.integrator}, cfl {t.cfl:g} (thesis eq. 5.52), t_end = {t.t_end:g}")
        if scene.shifting.method == "iips":
            lines.append(f"IIPS after each step, field update: {scene.iips.update} (thesis ch. 9)")
        if scheme.surface.active:
            lines.append(scheme.surface.describe())
        lines += describe_open(scene)
        if scene.initial.velocity == "taylor_green":
            lines.append("diagnostics against the analytic Taylor-Green vortex: L2|v_x - v_xA| (eq. 3.8), E_k")
        if scene.initial.velocity == "elliptical_drop":
            lines.append("diagnostics against the analytic elliptical drop (seed 002 section 3.4): semi-axes, "
                         "pressure")
        if scene.diagnostics.dam_break:
            lines.append("dam-break diagnostics (seed 001 section 6.3): surge front and residual column height")
        if scene.diagnostics.impinging_jet:
            lines.append("diagnostics against Taylor's wall pressure of an impinging jet (thesis eq. 3.3): "
                         "stagnation pressure, RMS error over |x| <= 2 H")
        if scene.output.probes:
            lines.append(f"{len(scene.output.probes)} probe(s): pressure and velocity at every history row in "
                         "OUT/probes.csv (Shepard interpolation of the fluid)")
        k = scene.packing
        if k.start:
            lines.append(f"the fluid starts at its positions in the snapshot {k.start} (packing.start)")
        if k.iterations:
            lines.append(f"particle packing first (seed 002 eq. 2.16): at most {k.iterations} iterations, alpha = "
                         f"{k.alpha:g}, cfl = {k.cfl:g}, until T < {k.tolerance:g} beta")
        return lines

    def __init__(self, scene, comm, out_dir, log=None, restart=None, progress=False):
        """restart: io.checkpoint.read_checkpoint's (state, particles, decomposition), to continue a run."""
        self.scene = scene
        self.scheme = make_scheme(scene)
        self.sim = Simulation(scene, comm, out_dir, specs=self.scheme.field_specs(),
                              halo_fields=self.scheme.halo_fields(), log=log, restart=restart, progress=progress)
        self.system = self.sim.system
        with self.closing_on_failure():
            self._build(scene, comm, restart)

    def _build(self, scene, comm, restart) -> None:
        """The set-up on the Simulation: packing, pre-procedure, initial fields, boundaries, IIPS, diagnostics."""
        self.resumed = resumed_state(restart, scene)
        self.pre, self.packing = None, None
        if restart is None and (scene.packing.iterations > 0 or scene.packing.start):
            self.packing = self.pack()
        if restart is None and scene.iips.pre_newton > 0:
            self.pre = self.pre_procedure()
        self.scheme.initialize(self.system, t=self.resumed["time"] if restart else 0.0, fresh=restart is None)
        self.open = make_open_boundaries(scene, self.system)
        if restart is None:
            self.open.start(self.system)
        self.emptied = False  # all the fluid has left (logged once)
        self.integrate = INTEGRATORS[scene.time.integrator]
        self.viscous_limit = ViscousLimit.of_scene(scene, self.scheme, self.system.kernel)
        self.reach = STAGE_REACH[scene.time.integrator]
        self.iips = None
        self.update = make_field_update(scene)
        # the volumes weighting the C that IIPS levels (with NFTS: V0, whose norms the history adds as
        # L2/Linf_grad_c0; its L2/Linf_grad_c weigh by the particles' volumes in every run)
        self.concentration_volume = "volume"
        if scene.shifting.method == "iips":
            from psph.shifting.iips import ImplicitShifting

            self.concentration_volume = self.update.concentration_volume
            self.iips = ImplicitShifting(scene.iips, self.sim.comm, volume=self.concentration_volume,
                                         surface=self.scheme.surface)
            if self.pre is not None:
                self.iips.set_initial_linf(self.pre["linf"])
        self.reference = REFERENCES[scene.initial.velocity](scene) if scene.initial.velocity in REFERENCES else None
        if scene.diagnostics.dam_break:
            self.reference = DamBreakReference(scene)
        if scene.diagnostics.impinging_jet:
            self.reference = ImpingingJetReference(scene, self.scheme.walls,
                                                   self.sim.out_dir if comm.rank == 0 else None,
                                                   resumed_at=self.resumed["time"] if restart else None)
        self.probes = None
        if scene.output.probes:
            self.probes = Probes(scene, self.sim.out_dir if comm.rank == 0 else None,
                                 resumed_at=self.resumed["time"] if restart else None)
            if self.probes.said:
                self.sim.log(f"psph: {self.probes.said}")
        elif restart and comm.rank == 0 and (self.sim.out_dir / PROBES_NAME).exists():
            # an in-place continuation without probes: the interrupted run's rows past the checkpoint go
            path = self.sim.out_dir / PROBES_NAME
            start_series(path, path.read_text().partition("\n")[0], resumed_at=self.resumed["time"])
        # the potential energy, where gravity has no component along a periodic axis (x wraps there)
        g = self.scheme.gravity
        self.potential = bool(np.any(g)) and not any(g[a] and scene.domain.periodic[a] for a in range(len(g)))
        self.initial_volume = allreduce_sum(self.sim.comm, float(
            self.system.particles.owned("volume")[fluid_mask(self.system)].sum()))
        self.first_dt = None
        self.fast_flow_told = False  # (check_reference_velocity, once per run segment)
        self.kept_stall = 0.0  # how far (in dx) this step's failed IIPS call's kept iterate moved a particle
        # time.retries: the halvings of the time step in effect, and the steps since the last change (a
        # checkpoint carries both, so a restart continues bit for bit; older ones were written at 0, 0)
        self.halvings, self.calm = 0, 0
        if self.resumed:
            self.initial_volume = self.resumed["initial_volume"]
            self.first_dt = self.resumed["first_dt"]
            self.halvings, self.calm = self.resumed.get("retry", (0, 0))
            self.packing = self.resumed.get("packing")  # (summary.json keeps the report after a restart too)
            if self.iips is not None:
                self.iips.restore(self.resumed["iips"])
            self.open.restore(self.resumed.get("open"))

    def pack(self) -> dict:
        """Colagrossi et al.'s particle packing (psph.packing, seed 002) before the fluid fields exist, from
        the fluid's positions in the snapshot packing.start if it names one, then the initial condition again
        at the packed positions; its history goes to OUT/packing.csv, also up to a failure, which writes the
        state. Collective."""
        from psph.packing import pack, start_from_snapshot

        rows, report, path = [], {}, self.scene.packing.start
        if path:
            report = start_from_snapshot(self.scene, self.system, path)
            self.sim.log(f"packing: the fluid starts at its positions in {path} (step {report['start_step']}, "
                         f"t = {report['start_time']:g})")
        if self.scene.packing.iterations > 0:
            try:
                with self.sim.diagnose_failures(lambda: (0, 0.0)):
                    report |= pack(self.scene, self.system, rows)
            finally:
                if self.sim.comm.rank == 0 and rows:
                    np.savetxt(self.sim.out_dir / "packing.csv", np.asarray(rows), delimiter=",", comments="",
                               header="iteration,kinetic_energy_over_beta,Linf_grad_gamma", fmt="%.10g")
            how = "T < tolerance" if report["converged"] else "the iteration limit (packing.iterations)"
            self.sim.log(f"packing: {report['iterations']} iteration(s) to {how}, T/beta = "
                         f"{report['kinetic_energy']:.2e}, Linf(grad Gamma) h {report['Linf_grad_gamma_start']:.3e} "
                         f"-> {report['Linf_grad_gamma']:.3e} (frame of {report['frame_particles']} particles), "
                         f"{report['time_s']:.1f} s")
        reset_initial_fields(self.scene, self.system.particles)
        return {k: v for k, v in report.items() if k != "rows"}

    def pre_procedure(self) -> dict:
        """The static pre-procedure (iips.pre_newton IIPS iterations, for every shifting method) before the
        fluid fields exist: from a perturbed lattice (initial.sigma_over_dx) it gives a relaxed start that
        the flow cannot strain into a squeezed lattice as it does the Cartesian one (docs/results.md, "From a
        relaxed start, with Morris' viscous operator").
        The initial condition is then set again at the moved positions. Collective."""
        start = time.perf_counter()
        with self.sim.diagnose_failures(lambda: (0, 0.0)):  # the state at a failure is written
            linf, iterations = pre_procedure(self.scene.iips, self.sim.comm, self.system,
                                             surface=make_free_surface(self.scene, pre_procedure=True))
        reset_initial_fields(self.scene, self.system.particles)
        pre = {"linf": linf, "time_s": time.perf_counter() - start}
        self.sim.log(f"pre-procedure: {iterations} IIPS iterations, Linf(grad C) = {linf:.3e}, "
                     f"{pre['time_s']:.1f} s")
        return pre

    def checkpoint(self, step, t, totals, next_output):
        """Write a checkpoint of the run at step and t (Simulation.checkpoint). Collective."""
        return self.sim.checkpoint(step, t, {
            "step": step, "time": t, "totals": totals, "next_output": next_output, "first_dt": self.first_dt,
            "initial_volume": self.initial_volume,
            "iips": self.iips.checkpoint_state() if self.iips is not None else None,
            "open": self.open.checkpoint_state(), "retry": [self.halvings, self.calm], "packing": self.packing})

    def new_totals(self) -> dict:
        """The run's counters and times at its start, which advance and run add to (history and summary):
        with IIPS, its field update's counters too (NFTS's fictitious sub-steps, thesis eq. 9.6; MLS's
        fits below the order)."""
        totals = {"iips_time_s": 0.0, "iips_newton": 0, "iips_linear": 0, "iips_calls": 0, "iips_failures": 0,
                  "retries": 0, "steps_redone": 0, "wall_reflections": 0, "step_time_s": 0.0}
        if self.iips is not None:
            totals.update(dict.fromkeys(self.update.counters, 0))
        return totals

    def advance(self, state, dt, vmax, totals, allowed=None) -> None:
        """One time step of size dt from state (step, time): integrate, shift, check. `allowed`: the step
        the CFL conditions allowed (and retries halved), of which dt is the part left to t_end; a collapse is
        of that step (a last step cut to 3.7e-10 to land on t_end was taken for one: a smoke test). Collective."""
        sim, system = self.sim, self.system
        t = state["time"]
        system.where = {"step": state["step"] + 1, "time": t}
        with phase("fluid_step"):
            system.prepare_step(self.reach * dt * vmax)
            self.scheme.detect_surface(system)  # the step's flags, for the shifting law and the tensile switch
            totals["steps_redone"] += self._integrate(t, dt, state["step"] + 1)
            self.scheme.end_step(system, dt)
            self.scheme.walls.place(system, t + dt)  # solids exactly where their bodies are at t + dt
            if self.scheme.walls.active:  # (its count is a collective)
                with phase("walls"):
                    self._reflect(step=state["step"] + 1, t=t + dt, totals=totals)
            # V = m / rho changed: IIPS and diagnostics read halo volumes and positions (an end of step
            # past half the skin rebuilds the lists, which carries every halo field)
            if not system.update():
                system.refresh(["volume"])
        state["step"] += 1
        state["time"] = t = t + dt
        step = state["step"]
        if self.open.active:  # inflow particles join the fluid, rows are emitted, outflow removed
            with phase("open_boundaries"):
                change = self.open.apply(system, t)
            # (collective: `change` and the inflows are every rank's)
            if change["removed"] and not self.open.inflows and not self.emptied \
                    and allreduce_sum(system.comm, int(fluid_mask(system).sum())) == 0:
                self.emptied = True
                self.sim.log(f"step {step}, t = {t:.6g}: all the fluid has left through the outflow; the run "
                             "goes on, empty, to time.t_end")
        self.kept_stall = 0.0
        if self.iips is not None:
            t0 = time.perf_counter()
            with phase("iips"):
                self.update.before(system, self.scheme)
                report = self.iips.correct(system, step=step, time=t)
                # no update where the particles stayed in place: a rejected call, or a stalled one whose
                # best iterate was its start (on_stall = "best")
                moved = self.iips.max_shift(system) if report.iterations and not report.rejected else 0.0
                if moved > 0.0:
                    for name, count in self.update.after(system, self.scheme).items():
                        totals[name] += count
                    self.open.extrapolate(system)  # the outflow buffer from the shifted fluid
            totals["iips_time_s"] += time.perf_counter() - t0
            totals["iips_newton"] += report.iterations
            totals["iips_linear"] += report.linear_iterations
            totals["iips_calls"] += int(report.iterations > 0)
            if report.failed:
                totals["iips_failures"] += 1
                # how far the kept iterate moved a particle: a stalled call's can be several dx (docs/results.md,
                # "Impinging jet")
                largest = f"; largest displacement {moved / self.scene.domain.dx:.2g} dx" if moved > 0.0 else ""
                sim.log(f"step {step}, t = {t:.4g}: {report.message}{largest}")
                self.kept_stall = moved / self.scene.domain.dx
        system.check_escaped()
        self.check(step, t, dt if allowed is None else allowed)

    def _reflect(self, step, t, totals) -> None:
        """Fluid particles that crossed a box container's side by up to half a dx are put back
        (WallTerms.reflect); the history's wall_reflections counts them, and the log names each step's
        deepest. One farther past is left where it is, for check to stop the run on, as past any other wall
        (`trespassers`; a density that left its range is named first): a wall audit fired a particle 19
        sqrt(gH) at a tank's floor, and any depth was put back, with one log line for the whole run naming
        neither the particle nor the place. Collective."""
        p = self.system.particles
        fluid = np.flatnonzero(fluid_mask(self.system))
        pos, vel = p.owned("position")[fluid], p.owned("velocity")[fluid]
        before, speed = pos.copy(), vel.copy()
        depth, body = self.scheme.walls.reflect(pos, vel)
        deep = depth > 0.5 * self.scene.domain.dx
        pos[deep], vel[deep], depth[deep] = before[deep], speed[deep], 0.0
        count = int(allreduce_sum(self.sim.comm, int(np.count_nonzero(depth))))
        if not count:
            return
        k = int(np.argmax(depth)) if len(depth) else 0  # (a rank may own no fluid: a review)
        mine = (float(depth[k]), int(p.owned("gid")[fluid[k]]), (tuple(before[k]), body[k])) \
            if len(depth) and depth[k] > 0.0 else None
        deepest = global_first(self.sim.comm, mine)
        deepest = (deepest[0], deepest[1], *deepest[2])
        p.owned("position")[fluid], p.owned("velocity")[fluid] = pos, vel
        self.sim.log(f"psph: step {step}, t = {t:.6g}: {count} fluid particle(s) crossed a wall of a box container "
                     f"and were mirrored back, the deepest {deepest[0] / self.scene.domain.dx:.2g} dx past the wall "
                     f"of body {deepest[3]!r}: particle gid {deepest[1]}, at "
                     f"({', '.join(f'{x:g}' for x in deepest[2])}) (history column wall_reflections)")
        totals["wall_reflections"] += count

    def _integrate(self, t, dt, step) -> int:
        """Integrate one step from t; if a stage went further than the neighbour lists hold, rebuild them at
        the step's start and take the step again. Returns the number of steps taken again (0 or 1).
        Collective."""
        system, scheme = self.system, self.scheme
        y0 = scheme.state(system)
        try:
            self.integrate(scheme, system, t, dt, y0)
            return 0
        except ListsExpired:
            scheme.set_state(system, y0)
        system.rebuild()
        try:
            self.integrate(scheme, system, t, dt)
        except ListsExpired as err:
            error = None
            if err.gid is not None:
                # the first stage that can catch it is half a step in (RK3 and RK4): a step goes twice as far
                needed = 4.0 * err.moved / system.kernel.support
                # (a stage half a step in, or a whole step in, caught it: the speed is at least moved / dt)
                speed, c0 = err.moved / dt, self.scene.physics.sound_speed
                if speed > c0:  # faster than sound: no skin holds this, the flow is blowing up
                    what = (f"a particle moved {err.moved:.3g} within a time step of {dt:.3g}, at {speed:.3g} or "
                            f"more, {speed / c0:.3g} times the speed of sound c0 = {c0:g}: the flow is blowing up")
                else:  # (the advice named the skin alone, also beyond its largest value, an audit found)
                    what = (f"a particle moved {err.moved:.3g} within one time step, more than half the "
                            f"neighbour-list skin ({0.5 * system.skin:.3g}); "
                            + hold_step_advice(needed, system.skin / system.kernel.support, self.scene.time.cfl))
                if speed > 3.0 * self.scene.physics.reference_velocity:
                    what += strength_advice(self.scene.shifting)
                error = NumericalError(what, step=step, time=t, gid=err.gid, position=err.position)
            raise_if_any(self.sim.comm, error)
        return 1

    def restore(self, arrays, t) -> None:
        """Put back the owned particles saved before a failed step (time.retries); fields the step
        added start from zero. Collective."""
        p = self.system.particles
        p.set_owned({name: arrays[name] if name in arrays else
                     np.zeros(spec.array_shape(len(arrays["gid"]), p.dim), dtype=spec.dtype)
                     for name, spec in p.specs.items()})
        self.system.rebuild(rebalance=False)
        self.scheme.initialize(self.system, t=t, fresh=False)

    # ---------------------------------------------------------------- pieces
    def check_reference_velocity(self, vmax, state) -> None:
        """Warn (the log, once) when the particles move faster than FAST_FLOW x physics.reference_velocity U
        and the shifting law takes U for the flow's largest speed: delta_plus's du = -Ma 2h c0 grad C^ with
        Ma = U / c0 and its cap U / 2 (seed 001 eq. 16-17), Lind's cap U / 2, Oger's U_char. The dam break
        (U = 1 by default) reaches 3.2 sqrt(g H): its shifting was 2-3 times weaker than seed 001's law
        and its cap as much tighter, without a word (a delta-ALE audit)."""
        phys = self.scene.physics
        if (self.fast_flow_told or self.scene.shifting.method not in ("delta_plus", "lind", "oger")
                or vmax <= FAST_FLOW * phys.reference_velocity):
            return
        self.fast_flow_told = True
        self.sim.log(f"psph: warning: step {state['step'] + 1}, t = {state['time']:.6g}: the particles move at "
                     f"{vmax:.4g}, {vmax / phys.reference_velocity:.2g} times physics.reference_velocity = "
                     f"{phys.reference_velocity:g}, which shifting.method = {self.scene.shifting.method!r} takes "
                     "for the flow's largest speed (its strength and cap scale with it): set it to about the "
                     "largest speed the flow reaches")

    def time_step(self, t) -> tuple:
        """(dt, the largest particle speed) at time t: the CFL step (time.cfl h / the largest signal speed,
        thesis eq. 5.52), capped by the viscous limit. Collective."""
        s, scheme = self.scene, self.scheme
        h = self.system.kernel.h
        vmax, signal = allreduce_max(self.sim.comm, scheme.max_speeds(self.system))
        dt = s.time.cfl * h / signal
        return min(dt, self.viscous_limit(self.system, dt, t)), float(vmax)

    def _min_spacing(self, mask, row_group, col_group) -> float:
        """The smallest distance, in dx, from an owned particle in `mask` to a neighbour j with col_group[j] ==
        row_group[i] (compute.sums.nearest_distance; inf if none on any rank). Collective."""
        nearest = np.empty(self.system.particles.n_owned)
        nearest_distance(self.system.particles["position"], self.system.nbr_ptr, self.system.nbr_idx, row_group,
                         col_group, nearest)
        return allreduce_min(self.sim.comm, float(nearest[mask].min()) if mask.any() else np.inf) / self.scene.domain.dx

    def diagnostics(self, t) -> dict:
        """The history row's diagnostics at time t (totals over every rank). Collective."""
        p, comm = self.system.particles, self.sim.comm
        mask = fluid_mask(self.system)
        m, u, rho, vol = p.owned("mass"), p.owned("velocity"), p.owned("density"), p.owned("volume")
        sums = allreduce_sum(comm, np.concatenate([
            [0.5 * float((m * (u * u).sum(axis=1))[mask].sum()), float(m[mask].sum()), float(vol[mask].sum())],
            (m[:, None] * u)[mask].sum(axis=0)]))
        drho = allreduce_max(comm, float(np.abs(rho[mask] / self.scheme.rho0 - 1.0).max()) if mask.any() else 0.0)
        surface = self.scheme.surface
        surface.detect(self.system)  # the flags where the particles are now (the step moved them)
        interior = surface.interior(self.system)
        if not surface.active and self.scene.describe_free_surface():
            # no detection (no shifting): the norms would be the surface's truncated supports, not the
            # distribution's disorder that they measure in every other run (a diagnostics audit: the tank at
            # rest gave L2 0.26), so they are left blank
            l2 = linf = float("nan")
        else:
            l2, linf = self._grad_c_norms("volume", interior)
        # (the fluid's, as every other column: an outlet buffer's counted too, a diagnostics audit)
        dvol = allreduce_max(comm, float(np.abs(vol[mask] / p.owned("volume0")[mask] - 1.0).max()) if mask.any()
                             else 0.0)
        speed = np.sqrt((u * u).sum(axis=1))[mask]
        vmax = allreduce_max(comm, float(speed.max()) if len(speed) else 0.0)
        out = {"kinetic_energy": sums[0], "total_mass": sums[1], "volume_error": sums[2] / self.initial_volume - 1.0,
               "max_speed": vmax, "min_spacing": self._min_spacing(mask, p["kind"], p["kind"]),
               "max_density_variation": drho, "max_volume_variation": dvol, "L2_grad_c": l2, "Linf_grad_c": linf}
        if self.scheme.walls.clones:  # solid particles: how near the fluid comes
            solid = (p["kind"] == Kind.WALL) | (p["kind"] == Kind.BODY)
            out["min_wall_spacing"] = self._min_spacing(mask, np.zeros(p.n_local, np.int8),
                                                        (~solid).astype(np.int8))
        if self.concentration_volume != "volume":  # IIPS + NFTS levels the reference volumes' C: its threshold's
            out["L2_grad_c0"], out["Linf_grad_c0"] = self._grad_c_norms(self.concentration_volume, interior)
        for a in range(p.dim):
            out[f"momentum_{'xyz'[a]}"] = sums[3 + a]
        if self.potential:  # -sum m g . x: kinetic + potential energy falls by the dissipation
            out["potential_energy"] = allreduce_sum(comm, -float((m[mask] * (p.owned("position")[mask]
                                                                             @ self.scheme.gravity)).sum()))
        if surface.active:
            out["surface_particles"] = surface.count(self.system)
        if self.open.active:
            out.update(self.open.budget(sums[1]))
        if self.reference is not None:
            out.update(self.reference.errors(self.system, t, sums[0]))
        out.update(self.scheme.walls.body_forces(comm))
        if self.probes is not None:
            self.probes.record(self.system, t)
        return out

    def _grad_c_norms(self, volume, rows) -> tuple:
        """(L2, Linf) of h grad C over the owned `rows`, C weighted by the field `volume` (ghost walls' images
        completing the supports). Every run's L2/Linf_grad_c weigh by the particles' volumes, the omega_j of
        thesis eq. 6.12: with IIPS + NFTS they were the reference volumes V0 that IIPS levels (a diagnostics
        audit: 4.9 times lower in L2 than the particles' in the thesis' Taylor-Green), now L2/Linf_grad_c0.
        Collective."""
        grad = grad_c(self.system, volume)
        self.scheme.walls.add_ghost_grad_c(self.system, 0.0, 1.0, 1.0, grad)
        return norms(self.sim.comm, grad, rows, self.system.kernel.h)

    def check(self, step, t, dt) -> None:
        """Stop all ranks, naming step, time, particle and position, on a broken state (step 0: the initial
        state, before any step). The density comes before a wall crossing: a blow-up crosses walls too. Of
        the first kind of problem any rank has, the particle named is the worst (the largest density or
        volume deviation), ties and the other kinds to the lowest gid, whatever the number of ranks (a style
        audit: the lowest rank's was named). Collective."""
        p = self.system.particles
        gids = p.owned("gid")
        bad = ~np.isfinite(p.owned("velocity")).all(axis=1) | ~np.isfinite(p.owned("density")) \
            | ~np.isfinite(p.owned("position")).all(axis=1) | ~np.isfinite(p.owned("volume")) \
            | ~np.isfinite(p.owned("mass"))  # (a review: a NaN volume passed, and hid the drift of its rank)
        dev = np.abs(p.owned("density") / self.scheme.rho0 - 1.0)
        limit = self.scene.physics.max_density_variation
        empty = (p.owned("density") <= 0.0) | (p.owned("volume") <= 0.0)

        def lowest(mask):
            rows = np.flatnonzero(mask)
            return int(rows[np.argmin(gids[rows])])

        def worst(values):
            return lowest(values == values.max())

        # ((-priority, key), gid, (problem, position, the initial density's hint)) of this rank's first kind
        local = None
        if bad.any():
            k = lowest(bad)
            local = ((0, 0.0), "non-finite field (NaN/Inf)", True)
        elif dev.size and dev.max() > limit:
            k = worst(dev)
            local = ((-1, float(dev[k])), f"density left the weakly compressible range: |rho/rho0 - 1| = "
                     f"{dev[k]:.3g} > {limit:g} (physics.max_density_variation)", dev[k] > 0.1)
        elif empty.any():  # (with physics.max_density_variation from 1 up, rho <= 0 passed: a failure audit)
            k = lowest(empty)
            local = ((-2, 0.0), f"a particle's density or volume fell to "
                     f"{min(p.owned('density')[k], p.owned('volume')[k]):.3g} (at or below zero)",
                     p.owned("density")[k] <= 0.0)
        elif (hit := self.scheme.walls.trespassers(
                p.owned("position")[fluid_mask(self.system)], t, 0.5 * self.scene.domain.dx,
                gids[fluid_mask(self.system)])) is not None:
            k = int(np.flatnonzero(fluid_mask(self.system))[hit[0]])
            local = ((-3, 0.0), f"a fluid particle crossed the wall of body {hit[1]!r}", False)
        elif self.scheme.variant == 0 and p.n_owned:
            drift = np.nan_to_num(np.abs(p.owned("volume") / p.owned("volume0") - 1.0), nan=np.inf)
            if drift.max() > (most := self.scene.physics.max_volume_variation):
                k = worst(drift)
                local = ((-4, float(drift[k])), f"particle volume drifted by {drift[k]:.3g} (> {most:g}, "
                         "physics.max_volume_variation)", False)
        if local is not None:
            local = (local[0], int(gids[k]), (local[1], p.owned("position")[k].copy(), bool(local[2])))
        first = global_first(self.sim.comm, local)
        problem, where = None, {}
        if first is not None:
            problem, where = first[2][0], {"gid": first[1], "position": first[2][1]}
        if problem is None and not dt > 0.0:  # a speed whose square overflows: every step, 0 (ran on at t = 0)
            problem = f"time step collapsed to {dt:.3g}"
        elif problem is None and self.first_dt and dt < DT_COLLAPSE * self.first_dt:
            problem = f"time step collapsed to {dt:.3g} (first step {self.first_dt:.3g})"
        if problem is None:
            return
        if self.kept_stall > 0.0:  # (an audit of IIPS in free-surface flows: the dam break at h/dx = 1.4
            # stopped on a volume drift, the stall only in the line before)
            problem += (f" (this step's IIPS call had failed and kept an iterate that moved a particle "
                        f"{self.kept_stall:.2g} dx, which iips.update = {self.scene.iips.update!r} took in: "
                        "iips.on_stall / iips.on_failure = \"reject\" undo such calls)")
        if step == 0:
            problem = f"the initial state: {problem}"
            if first is not None and first[2][2]:  # the initial fields' density (NaN, beyond 10% or <= 0), not a
                # tight limit's (a review: the <= 0 case had lost the hint)
                problem += (" (the initial density follows the initial pressure and gravity through the equation "
                            "of state, which needs |p| << rho0 c0^2: physics.sound_speed)")
        error = NumericalError(problem, step=step, time=t, **where)
        error.collective = True  # (every rank raises it)
        raise error

    # ------------------------------------------------------------------ run
    def run(self) -> dict:
        """Run to time.t_end (or a stop); returns the summary. Collective."""
        sim, scene, system = self.sim, self.scene, self.system
        t_end = scene.time.t_end
        every = scene.output.every
        next_output = every if every > 0 else math.inf
        totals = self.new_totals()
        state = {"step": 0, "time": 0.0}
        if self.resumed:
            state = {"step": self.resumed["step"], "time": self.resumed["time"]}
            totals.update(self.resumed["totals"])
            next_output = self.resumed["next_output"]
            sim.log(f"psph: continuing from step {state['step']}, t = {state['time']:.6g}")
        last_checkpoint = time.monotonic()
        with sim.diagnose_failures(lambda: (state["step"], state["time"])):
            # a start the scheme cannot take stops here, not at step 1; a checkpoint's state is checked again
            # (one edited by hand: a fluid particle put inside a wall was mirrored back without a word)
            self.check(state["step"], state["time"], math.inf)
            if not self.resumed:
                sim.history.append({"time": 0.0, "step": 0, "dt": 0.0, **self.diagnostics(0.0), **totals})
                sim.snapshots.write(system.particles, step=0, time=0.0)
            sim.settle()
            progress = sim.progress(state["time"], t_end)
            while state["time"] < t_end * (1.0 - 1e-12):
                start = time.perf_counter()
                dt, vmax = self.time_step(state["time"])
                self.first_dt = self.first_dt or dt
                self.check_reference_velocity(vmax, state)
                allowed = dt * 0.5 ** self.halvings
                dt = min(allowed, t_end - state["time"])
                saved = ((dict(state), system.particles.owned_arrays(), self.open.checkpoint_state())
                         if scene.time.retries else None)
                try:
                    self.advance(state, dt, vmax, totals, allowed)
                except NumericalError as err:
                    if saved is None or self.halvings >= scene.time.retries:
                        raise
                    self.halvings, self.calm = self.halvings + 1, 0
                    sim.log(f"step {saved[0]['step'] + 1}, t = {saved[0]['time']:.6g}: {err}; retrying with "
                            f"dt x {0.5 ** self.halvings:g} (time.retries: {self.halvings} of {scene.time.retries})")
                    state.update(saved[0])
                    self.restore(saved[1], state["time"])
                    self.open.restore(saved[2])
                    totals["retries"] += 1
                    continue
                if self.halvings:  # back towards the full step, a doubling at a time
                    self.calm += 1
                    if self.calm == RECOVERY_STEPS:
                        self.halvings, self.calm = self.halvings - 1, 0
                step, t = state["step"], state["time"]
                totals["step_time_s"] += time.perf_counter() - start
                if step % scene.output.history_every == 0 or t >= t_end * (1.0 - 1e-12):
                    sim.history.append({"time": t, "step": step, "dt": dt, **self.diagnostics(t), **totals})
                if t >= next_output - 1e-9 * dt:
                    sim.snapshots.write(system.particles, step=step, time=t)
                    sim.log(f"t = {t:.4g}, step {step}, dt = {dt:.3g}")
                    next_output += every
                written = None  # this step's checkpoint, if one was due
                if t < t_end * (1.0 - 1e-12) and sim.checkpoint_due(step, last_checkpoint):
                    written = self.checkpoint(step, t, totals, next_output)
                    last_checkpoint = time.monotonic()
                if t < t_end * (1.0 - 1e-12) and sim.stop_requested():
                    progress.close()
                    written = written or self.checkpoint(step, t, totals, next_output)
                    # after the checkpoint: a continuation writes its next snapshot over this one, as the run
                    # that was never stopped would
                    sim.stop(checkpoint_message(step, t, written, sim.comm.size, sim.snapshot_once(step, t)))
                progress.update(step, t, dt, **({"newton": totals["iips_newton"], "ksp": totals["iips_linear"]}
                                                if self.iips is not None else {}))
            progress.close()
        step, t = state["step"], state["time"]
        sim.snapshot_once(step, t)
        final = sim.history.rows[-1]
        sim.log(f"t = {t:.4g} after {step} steps" + (f": L2|v_x - v_xA| = {final['L2_vx_error']:.4e}"
                                                       if "L2_vx_error" in final else ""))
        steps_min = allreduce_min(sim.comm, step)
        return sim.summary(steps=steps_min, final={k: v for k, v in final.items() if k != "time"} | {"time": t},
                           **totals, **({"packing": self.packing} if self.packing else {}))
