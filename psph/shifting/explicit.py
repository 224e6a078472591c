"""Explicit iterative Fickian shifting, the baseline IIPS is compared with (thesis 000 section 8.3.1).

Each iteration moves every free particle down the concentration gradient (Lind et al. 2012, thesis
eq. 6.13):  dx_i = -D grad C_i,  D = `shifting.diffusion` h^2. Lind et al. (and the thesis) use
0.5 h^2; with Wendland C6 at h/dx = 2 that iteration diverges (measured: stable up to about 0.46 h^2),
so psph's default is 0.4 h^2. Above that limit the iteration amplifies the shortest wavelengths: a call
whose L2(grad C) grows past GROWTH times its start has diverged (at 0.5 h^2 it grows by at most 1.95 in
2000 iterations, where the static study lets it run; at 5 h^2 it grows 7-fold at the first iteration).
The static study iterates it (`shifting.max_iterations`); time-dependent runs apply
`shifting.iterations_per_step` iterations per step. One iteration per step with D = (c0 dt)^2 is the
thesis' non-iterative explicit shifting of eq. 8.36 (Procedure C), whose printed sign is read as moving
particles towards lower concentration, like eq. 6.13.
"""

import time

import numpy as np

from psph.errors import NumericalError
from psph.particles import Kind
from psph.shifting.base import Shifting, ShiftReport, measure

GROWTH = 4.0


class ExplicitIterativeShifting(Shifting):
    name = "explicit_iterative"

    def __init__(self, spec):
        self.spec = spec
        self.iterations = 0

    def correct(self, system, on_iteration=None, iterations=None, **where) -> ShiftReport:
        n = self.spec.iterations_per_step if iterations is None else iterations
        coeff = self.spec.diffusion * system.kernel.h ** 2
        grad, l2, linf = measure(system)
        start = l2
        report = ShiftReport(L2_grad_c=l2, Linf_grad_c=linf)
        while report.iterations < n:
            t0 = time.perf_counter()
            p = system.particles
            free = p.owned("kind") == Kind.FLUID
            p.owned("position")[free] -= coeff * grad[free]
            system.update()
            grad, l2, linf = measure(system)
            report.iterations += 1
            self.iterations += 1
            report.L2_grad_c, report.Linf_grad_c = l2, linf
            if not np.isfinite(l2) or l2 > GROWTH * start:
                raise NumericalError(f"explicit iterative shifting diverged at iteration {report.iterations}: "
                                     f"L2(grad C) grew from {start:.3e} to {l2:.3e} (shifting.diffusion = "
                                     f"{self.spec.diffusion:g}: lower it; Wendland C6 at h/dx = 2 is stable up "
                                     "to about 0.46)", **where)
            if on_iteration is not None and on_iteration(
                    {"newton": report.iterations, "ksp_iterations": 0, "L2_grad_c": l2, "Linf_grad_c": linf,
                     "newton_time_s": time.perf_counter() - t0}):
                break
        return report
