"""physics.scheme = "none": a static particle distribution, measured (and, with shifting, improved).

history.csv gets one row per iteration (iteration 0 is the initial state); snapshots hold the initial
and the final state; summary.json the final diagnostics and the Cartesian-lattice reference value of
L2(d f/dx) at the same resolution (thesis figs 8.5-8.6, dashed lines).
"""

from psph.diagnostics import distribution_report, grad_c
from psph.simulation import Simulation, build_system, unperturbed


class StaticDriver:
    @staticmethod
    def describe(scene) -> list:
        return ["physics none: particles do not move",
                "diagnostics: L2/Linf(grad C) (thesis eq. 3.4-3.5), L2(d f/dx) (eq. 3.7, "
                f"wavelength {scene.diagnostics.test_wavelength:g} = "
                f"{scene.diagnostics.test_wavelength / scene.domain.dx:g} particles)"]

    def __init__(self, scene, comm, out_dir, log=None):
        self.scene = scene
        self.sim = Simulation(scene, comm, out_dir, log=log)

    def cartesian_reference(self) -> float:
        """L2(d f/dx) on the unperturbed lattice of the same scene. Collective."""
        scene = self.scene
        system = build_system(unperturbed(scene), self.sim.comm)
        return distribution_report(system, scene.diagnostics.test_wavelength)["L2_dfdx"]

    def run(self) -> dict:
        sim = self.sim
        system = sim.system
        wavelength = self.scene.diagnostics.test_wavelength
        reference = self.cartesian_reference()
        grad = grad_c(system)
        report = distribution_report(system, wavelength, grad)
        sim.history.append({"time": 0.0, "iteration": 0, **report, "L2_dfdx_cartesian": reference})
        sim.snapshots.write(system.particles, step=0, time=0.0, extra={"grad_c": grad})
        sim.log(f"L2(grad C) = {report['L2_grad_c']:.4e}, Linf(grad C) = {report['Linf_grad_c']:.4e}, "
                f"L2(df/dx) = {report['L2_dfdx']:.4e} (Cartesian {reference:.4e})")
        return sim.summary(steps=0, final={**report, "L2_dfdx_cartesian": reference})
