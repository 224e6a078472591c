"""physics.scheme = "none": a static particle distribution, measured and, with a shifting method,
improved iteration by iteration (thesis 8.3.1, Algorithm 1).

history.csv gets one row per iteration (iteration 0 is the initial state; its time column is the iteration,
as a snapshot's time is) with L2/Linf(grad C),
L2(d f/dx), the linear iterations and the cumulative shifting time; snapshots hold the initial and the
final state; summary.json the final diagnostics and the Cartesian-lattice reference value of L2(d f/dx)
at the same resolution (the dashed lines of thesis figs 8.5-8.6).
"""

from psph.diagnostics import distribution_report, grad_c
from psph.drivers.base import Driver
from psph.shifting import make_shifting
from psph.simulation import Simulation, build_system, unperturbed


class StaticDriver(Driver):
    @staticmethod
    def describe(scene) -> list:
        d = scene.diagnostics
        lines = ["physics none: particles move only by shifting",
                 "diagnostics: L2/Linf(grad C) (thesis eq. 3.4-3.5), L2(d f/dx) (eq. 3.7, wavelength "
                 f"{d.test_wavelength:g} = {d.test_wavelength / scene.domain.dx:g} particles)"]
        surface = scene.describe_free_surface()
        if surface and scene.shifting.method == "iips":
            lines.append(f"free surface ({surface}): IIPS leaves its particles where they are, detected as in a "
                         "flow's pre-procedure (thesis 10.2.1)")
        if d.stop_at_cartesian > 0:
            lines.append(f"stop when L2(d f/dx) <= {d.stop_at_cartesian:g} x its Cartesian-lattice value")
        return lines

    def __init__(self, scene, comm, out_dir, log=None, progress=False):  # progress: one line per iteration
        self.scene = scene
        self.sim = Simulation(scene, comm, out_dir, log=log)
        with self.closing_on_failure():
            self.shifting = make_shifting(scene, self.sim.comm)

    @staticmethod
    def _check_improved(sim, report, iterations, path) -> None:
        """A run that leaves the distribution worse than it found it (L2(grad C) above iteration 0's, not at
        round-off) failed, whatever its last iterations did: NumericalError naming the best iteration (an
        audit: the cubic spline at h/dx = 2 went 0.055 -> 0.0094 -> 0.37 and ended at 0.135, exit 0). One
        that got far below its start first and then drifted (a near-lattice start iterated long past
        convergence: the printed operator is not the exact Jacobian) is told how to stop there. Collective:
        the rows and values are every rank's."""
        from psph.errors import NumericalError
        from psph.scene.schema import ROUNDOFF_LINF

        rows = sim.history.rows
        start = rows[0]["L2_grad_c"]
        if report["L2_grad_c"] <= start * (1.0 + 1e-9) or report["Linf_grad_c"] <= ROUNDOFF_LINF:
            return
        best = min(rows, key=lambda r: r["L2_grad_c"])
        if best["L2_grad_c"] < 1e-2 * start:
            why = (f"it converged and then drifted away (fewer iterations, iips.threshold, iips.backtrack or "
                   f"diagnostics.stop_at_cartesian stop near iteration {best['iteration']})")
        else:
            why = ("it diverged (a kernel that pairs particles, as the cubic spline does at h/dx = 2, or too large "
                   "a step)")
        sim.history.flush()
        error = NumericalError(f"the shifting left the distribution worse than it started: L2(grad C) {start:.3g} -> "
                               f"{report['L2_grad_c']:.3g} (lowest {best['L2_grad_c']:.3g} at iteration "
                               f"{best['iteration']}): {why}; the state is in {path}", iteration=iterations)
        error.collective = True  # every rank raises it: one line, not an abort
        raise error

    def cartesian_reference(self) -> float:
        """L2(d f/dx) on the unperturbed lattice of the same scene. Collective."""
        scene = self.scene
        system = build_system(unperturbed(scene), self.sim.comm)
        value = distribution_report(system, scene.diagnostics.test_wavelength)["L2_dfdx"]
        system.close()
        return value

    def run(self) -> dict:
        sim, scene = self.sim, self.scene
        system = sim.system
        wavelength = scene.diagnostics.test_wavelength
        reference = self.cartesian_reference()
        stop_ratio = scene.diagnostics.stop_at_cartesian
        report = distribution_report(system, wavelength)
        elapsed = {"shifting_time_s": 0.0, "linear_iterations": 0}
        sim.history.append({"time": 0.0, "iteration": 0, **report, "L2_dfdx_cartesian": reference,
                            "ksp_iterations": 0, "linear_iterations": 0, "shifting_time_s": 0.0})
        # a snapshot's time, and a history row's, is its iteration: ParaView steps through them (two at time 0
        # read as one time step, whose data it cannot show), and the history's time axis matches theirs
        sim.snapshots.write(system.particles, step=0, time=0.0, extra={"grad_c": grad_c(system)})
        sim.log(f"iteration 0: L2(grad C) = {report['L2_grad_c']:.4e}, L2(df/dx) = {report['L2_dfdx']:.4e} "
                f"(Cartesian {reference:.4e})")

        stopped = []

        def on_iteration(info):
            nonlocal report
            elapsed["shifting_time_s"] += info["newton_time_s"]
            elapsed["linear_iterations"] += info["ksp_iterations"]
            report = distribution_report(system, wavelength)
            sim.history.append({"time": float(info["newton"]), "iteration": info["newton"], **report,
                                "L2_dfdx_cartesian": reference, "ksp_iterations": info["ksp_iterations"], **elapsed})
            sim.log(f"iteration {info['newton']}: L2(grad C) = {report['L2_grad_c']:.4e}, "
                    f"L2(df/dx) = {report['L2_dfdx']:.4e}, KSP iterations {info['ksp_iterations']}")
            stopped.append(sim.stop_requested())
            system.where = {"iteration": info["newton"] + 1}  # a failure's label (check_escaped, IIPS's errors)
            return stopped[-1] or (stop_ratio > 0 and report["L2_dfdx"] <= stop_ratio * reference)

        system.where = {"iteration": 1}
        sim.settle()
        try:
            with sim.diagnose_failures(lambda: (len(sim.history.rows), float(len(sim.history.rows)))):
                result = self.shifting.correct(system, on_iteration, iterations=scene.shifting.max_iterations)
        finally:
            system.where = {}
        iterations = len(sim.history.rows) - 1  # an iteration iips.backtrack undid has no row, nor a state
        kept = iterations  # the iteration whose state the run ends with
        if result.message:
            sim.log(result.message)
        if result.failed:  # kept: the best iterate, the start (reject) or a diverged step (warn)
            kept = iterations if result.kept_iteration is None else min(result.kept_iteration, iterations)
            report = distribution_report(system, wavelength)
            sim.log(f"the state kept, iteration {kept}'s: L2(grad C) = {report['L2_grad_c']:.4e}, Linf(grad C) = "
                    f"{report['Linf_grad_c']:.4e}, L2(df/dx) = {report['L2_dfdx']:.4e} (the last snapshot's and "
                    f"summary.json's final values)")
        if kept:
            # labelled with the kept state's iteration (a diagnostics audit: a stalled run's best iterate, 7,
            # was written as iteration 12's); a run that kept its start has it in the first snapshot
            path = sim.snapshots.write(system.particles, step=kept, time=float(kept), extra={"grad_c": grad_c(system)})
        elif iterations:
            path = sim.out_dir / sim.snapshots.entries[0][0]
        if iterations:
            if stopped and stopped[-1]:  # (a failed first iteration reports none)
                sim.stop(f"the state after iteration {iterations} is in {path} (static runs write no checkpoint)")
            if not result.failed:  # (a failed call kept the state its on_stall / on_failure chose, and said so)
                self._check_improved(sim, report, iterations, path)
        return sim.summary(steps=iterations, final={**report, "L2_dfdx_cartesian": reference, "iteration": kept},
                           shifting_time_s=elapsed["shifting_time_s"],
                           linear_iterations=elapsed["linear_iterations"])
