"""Kernels of the explicit particle-shifting laws (numba). The laws themselves (coefficients, limiters)
are in psph/shifting/velocity.py.

Sign convention: grad_i W_ij = f(r) x_ij, x_ij = x_i - x_j, points from i to j for a decreasing kernel
(f < 0), so grad C_i points up the concentration; shifting moves particles down it (dx = -D grad C). The
thesis prints some of these laws with grad W_ij = d W / d x_j (eq. 8.6), i.e. the opposite sign; psph uses
the physical direction.
"""

import numpy as np
from numba import njit

from psph.compute.jit import per_dimension
from psph.compute.smoothing import kernel_f, kernel_w
from psph.compute.sums import dot, load, pair2, store


@njit(cache=True, inline="always")
def fast_power(x, n):
    """x^n, by multiplication when n is a small whole number (pow() is slow in the pair loop)."""
    if n == 4.0:
        x2 = x * x
        return x2 * x2
    if n == 2.0:
        return x * x
    return x ** n


@njit(cache=True, inline="always")
def grad_c_weight(r, f, vol_j, kp, coeff, power, w_ref):
    """The pair weight of the corrected grad C (thesis eq. 6.15): [1 + coeff (W_ij / W(dx))^power] F_ij V_j,
    grad_i W_ij = F_ij (x_i - x_j). Shared by corrected_grad_c and the fused pass of compute.fluid."""
    s = f * vol_j
    if coeff != 0.0:
        s *= 1.0 + coeff * fast_power(kernel_w(r, kp) / w_ref, power)
    return s


def _compile_grad_c(d):
    """corrected_grad_c for dimension d, a compile-time constant (as in compute.fluid)."""

    @per_dimension(d)
    def grad_c(pos, vol, ptr, idx, kp, coeff, power, w_ref, out):
        support2 = 4.0 * kp[1] * kp[1]
        for i in range(ptr.size - 1):
            g0 = g1 = g2 = 0.0
            for k in range(ptr[i], ptr[i + 1]):
                j = idx[k]
                x0, x1, x2, rr = pair2(pos, i, j, d)
                if rr >= support2:  # a list pair in the skin adds exactly zero: skip its kernel values
                    continue
                r = np.sqrt(rr)
                s = grad_c_weight(r, kernel_f(r, kp), vol[j], kp, coeff, power, w_ref)
                g0 += s * x0
                if d > 1:
                    g1 += s * x1
                if d > 2:
                    g2 += s * x2
            store(out, i, d, g0, g1, g2)

    return grad_c


_GRAD_C = {d: _compile_grad_c(d) for d in (1, 2, 3)}


def corrected_grad_c(pos, vol, ptr, idx, kp, coeff, power, w_ref, out):
    """grad C^_i = sum_j [1 + coeff (W_ij / W(dx))^power] grad_i W_ij V_j (thesis eq. 6.15; seed 001
    eq. 17 with R = coeff, n = power). coeff = 0 gives the plain grad C."""
    _GRAD_C[pos.shape[1]](pos, vol, ptr, idx, kp, coeff, power, w_ref, out)


@njit(cache=True)
def limit_magnitude(vec, limit, out):
    """out_i = vec_i scaled down to |out_i| <= limit_i (limit: per-particle array)."""
    for i in range(vec.shape[0]):
        norm = np.sqrt(np.sum(vec[i] * vec[i]))
        scale = 1.0
        if norm > limit[i] and norm > 0.0:
            scale = limit[i] / norm
        for a in range(vec.shape[1]):
            out[i, a] = vec[i, a] * scale


def _compile_neuhauser(d):
    """neuhauser_acceleration for dimension d, a compile-time constant (as in compute.fluid)."""

    @per_dimension(d)
    def acceleration(pos, vol, v0, pref, ptr, idx, kp, c0, alpha, out):
        smooth_scale = alpha * c0 / kp[1]
        for i in range(ptr.size - 1):
            a0 = a1 = a2 = 0.0
            vi0, vi1, vi2 = load(v0, i, d)
            for k in range(ptr[i], ptr[i + 1]):
                j = idx[k]
                x0, x1, x2, rr = pair2(pos, i, j, d)
                if rr == 0.0:
                    continue
                r = np.sqrt(rr)  # beyond the support both kernel factors below are zero: no branch
                vj0, vj1, vj2 = load(v0, j, d)
                dv0, dv1, dv2 = vi0 - vj0, vi1 - vj1, vi2 - vj2
                approach = -dot(dv0, dv1, dv2, x0, x1, x2, d) / r  # (v0_i - v0_j) . e_ij, e_ij = -x_ij / r
                s = (0.5 * (pref[i] + pref[j]) + 0.5 * c0 * approach) * kernel_f(r, kp) * vol[j]
                smooth = smooth_scale * kernel_w(r, kp) * vol[j]
                a0 -= s * x0 + smooth * dv0
                if d > 1:
                    a1 -= s * x1 + smooth * dv1
                if d > 2:
                    a2 -= s * x2 + smooth * dv2
            store(out, i, d, a0, a1, a2)

    return acceleration


_NEUHAUSER = {d: _compile_neuhauser(d) for d in (1, 2, 3)}


def neuhauser_acceleration(pos, vol, v0, pref, ptr, idx, kp, c0, alpha, out):
    """Smoothed transport-velocity correction of Neuhauser (thesis eq. 6.33-6.34, with P_S eq. 7.1 or the
    fictitious pressure eq. 7.4 through pref):

        a_i = -sum_j [(pref_i + pref_j) / 2 + c0/2 (v0_i - v0_j) . e_ij] grad_i W_ij V_j
              - alpha c0 / h sum_j (v0_i - v0_j) W_ij V_j,           e_ij = (x_j - x_i) / |x_j - x_i|

    pref is the reference pressure over rho0 per particle (P_S p_ref / rho0, or P^F / rho0). The first
    sum pushes particles down the concentration gradient and, through the upwind term, resists their
    approach; the second smooths the transport velocity. (Solid-boundary terms: walls issue.)

    Signs: read with the thesis' own grad_i W_ij (eq. 5.48), eq. 6.33 and 7.1 as printed would pull
    particles together, and eq. 7.4 prints the opposite sign to them; the thesis never defines its n_ij.
    psph takes the repulsive reading above with e_ij from i to j
    (tests/compute/test_shift_velocity.py::test_neuhauser_pushes_a_pair_apart_and_harder_as_it_closes)."""
    _NEUHAUSER[pos.shape[1]](pos, vol, v0, pref, ptr, idx, kp, c0, alpha, out)
