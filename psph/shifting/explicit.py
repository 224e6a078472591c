"""Explicit iterative Fickian shifting, the baseline IIPS is compared with (thesis 000 section 8.3.1).

Each iteration moves every free particle down the concentration gradient (Lind et al. 2012, thesis
eq. 6.13):  dx_i = -D grad C_i,  D = `shifting.diffusion` h^2. Lind et al. (and the thesis) use
0.5 h^2; with Wendland C6 at h/dx = 2 that iteration diverges (stable up to 0.47 h^2: stability_limit;
measured about 0.46 h^2), so psph's default is 0.4 h^2, which in turn exceeds the limit at smaller h/dx
(0.40 h^2 at 1.6, 0.27 h^2 at 1.3: a run above it is warned about). Above that limit the iteration
amplifies the shortest wavelengths: a call whose L2(grad C) grows past GROWTH times its start has
diverged (at 0.5 h^2 it grows by at most 1.95 in 2000 iterations, where the static study lets it run; at
5 h^2 it grows 7-fold at the first iteration).
The static study iterates it (`shifting.max_iterations`); time-dependent runs apply
`shifting.iterations_per_step` iterations per step. One iteration per step with D = (c0 dt)^2 is the
thesis' non-iterative explicit shifting of eq. 8.36 (Procedure C), whose printed sign is read as moving
particles towards lower concentration, like eq. 6.13.
"""

import time

import numpy as np

from psph.diagnostics import fluid_mask
from psph.errors import NumericalError
from psph.particles import Kind
from psph.shifting.base import Shifting, ShiftReport, measure, steepest

GROWTH = 4.0


def stability_limit(kernel_name: str, dim: int, h_over_dx: float, weights=(0.0, 4.0)) -> float:
    """The largest D / h^2 for which dx = -D grad C (thesis eq. 6.13) does not amplify the shortest waves of
    a perturbation of the Cartesian lattice of spacing dx; with `weights` (b, n), of dx = -D grad C^, whose
    pairs are weighted by phi = 1 + b (W_ij / W(dx))^n (Lind's law, thesis eq. 6.15-6.16: b = 0.2, n = 4).

    Linearised about the lattice, grad C_i changes by sum_j V H(x_ij) (d_i - d_j), H the Jacobian of the pair
    term phi(r) grad W(x): H = phi HessW + b n (W / W(dx))^(n-1) / W(dx) grad W grad W^T (plain: HessW).
    For a wave d_j = d exp(i k.x_j) that is K(k) d with the symbol K(k) = sum_j V H(x_j) (1 - cos k.x_j), so
    an iteration multiplies the wave by I - D K(k): the short waves stay bounded while D <= 2 / max_k
    lambda_max(K(k)). The symbol is even in each component of k, so k ranges over [0, pi / dx]^d.
    In 2-D and 3-D K(k) also has a negative eigenvalue, the rows of the square lattice sliding along each
    other (k = (pi, 0)): that wave grows at any D, by 1 + D |lambda_min| per iteration, slowly with the
    plain gradient (lambda_min = -0.0016 with C6 at h/dx = 2, against a largest 1.06) and 47 times faster
    with Lind's weights (-0.076): the lattice is not where the corrected law rests, and a flow leaves it."""
    from psph.compute.smoothing import make_kernel
    from psph.schemes.viscous_limit import lattice_offsets, zone_maximum

    kernel = make_kernel(kernel_name, dim, h_over_dx)  # dx = 1
    offsets, _, _ = lattice_offsets(kernel, dim, 1.0)
    jacobian = kernel.hessian(offsets)
    coeff, power = weights
    if coeff:
        ratio = kernel.value(np.linalg.norm(offsets, axis=1)) / kernel.value(np.array([1.0]))[0]
        grad = kernel.gradient(offsets)
        jacobian = ((1.0 + coeff * ratio ** power)[:, None, None] * jacobian
                    + (coeff * power * ratio ** (power - 1) / kernel.value(np.array([1.0]))[0])[:, None, None]
                    * np.einsum("ja,jb->jab", grad, grad))
    def largest(k):
        return np.linalg.eigvalsh(np.einsum("kj,jab->kab", 1.0 - np.cos(k @ offsets.T), jacobian))[:, -1]

    return 2.0 / zone_maximum(largest, dim, np.pi) / h_over_dx ** 2


class ExplicitIterativeShifting(Shifting):
    name = "explicit_iterative"

    def __init__(self, spec, domain=None):
        """domain: the scene's domain section, whose kernel's lattice limit (stability_limit) a divergence
        names (without it, the message names the function)."""
        self.spec, self.domain = spec, domain
        self.iterations = 0

    def _limit(self) -> str:
        """The divergence message's words on the lattice limit (computed only then)."""
        d = self.domain
        if d is None:
            return "the lattice's stability limit (psph.shifting.explicit.stability_limit)"
        return (f"{d.kernel} at h/dx = {d.h_over_dx:g} is stable up to "
                f"{stability_limit(d.kernel, d.dimension, d.h_over_dx):.3g} on the lattice")

    def correct(self, system, on_iteration=None, iterations=None, **where) -> ShiftReport:
        """Iterations dx = -D grad C (thesis eq. 6.13), D = shifting.diffusion h^2. Collective."""
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
            if not np.isfinite(l2) or l2 > GROWTH * start:  # (l2 is every rank's: all raise it)
                place = {**system.where, **where, **steepest(system, grad, np.flatnonzero(fluid_mask(system)))}
                error = NumericalError(f"explicit iterative shifting diverged at iteration {report.iterations}: "
                                       f"L2(grad C) grew from {start:.3e} to {l2:.3e} (shifting.diffusion = "
                                       f"{self.spec.diffusion:g}: lower it; {self._limit()})", **place)
                error.collective = True
                raise error
            if on_iteration is not None and on_iteration(
                    {"newton": report.iterations, "ksp_iterations": 0, "L2_grad_c": l2, "Linf_grad_c": linf,
                     "newton_time_s": time.perf_counter() - t0}):
                break
        return report
