"""Field updates after an IIPS correction (thesis 000 chapter 9; numba).

NFTS, the fictitious time step (eq. 9.5-9.7): with s_i = dx_i / N, one of the N sub-steps is
    V_i'        = V_i + V_i sum_j (s_j - s_i) . grad_i W_ij V_j
    (V rho)_i'  = (V rho)_i + V_i sum_j (rho_i s_i + rho_j s_j) . grad_i W_ij V_j
    (V rho u)_i' = (V rho u)_i + V_i sum_j (rho_i u_i (s_i . grad_i W_ij) + rho_j u_j (s_j . grad_i W_ij)) V_j
followed by x_i' = x_i + s_i. The thesis prints the mass and momentum lines with a minus sign; with the
grad_i W_ij its volume line uses, only the plus sign keeps a uniform state uniform (moving a volume through
fluid at rest gains the mass it sweeps: d(m) = rho dV); tests/compute/test_field_update.py checks it and the
exact conservation of total mass and momentum.

MLS re-interpolation (eq. 9.8 first order, 9.9 second order): for the new position x_i of a particle and
the old particles j around it, solve sum_j W_ij V_j P_ij P_ij^T a = sum_j phi_j W_ij V_j P_ij with
P_ij = (1, x_ij / h, ...) (the monomials up to the order) and take phi_i = a_0.
"""

import numpy as np
from numba import njit

from psph.compute.smoothing import kernel_f, kernel_w
from psph.compute.sums import pair, solid


@njit(cache=True)
def nfts_increments(pos, vol, rho, vel, step, kind, normal, ptr, idx, kp, d_vol, d_mass, d_mom):
    """Increments of V, V rho and V rho u for one fictitious sub-step of displacement `step` (owned rows).

    A solid neighbour j (a wall's or a body's) is a clone of i (seed 004 section III, as for the shifting terms of
    the right-hand side): its step is i's mirrored in the wall, s_j = s_i - 2 (s_i . n_j) n_j, so the pair
    changes i's volume by the normal part of the step only, -2 V_i (s_i . n_j) (n_j . grad W_ij) V_j (a
    particle moved towards the wall is squeezed). Mass and momentum do not cross a wall: a solid pair adds
    no flux to them. (The mirrored pair's mass flux rho (s_i + s_j) . grad W_ij is tangential. It vanishes
    for a mirror image across a straight wall, but the solids are a fixed lattice, not mirror images, and
    next to corners and disordered particles it made mass: -0.35% in the lid-driven cavity at L/dx = 25
    by t = 6, IIPS + NFTS.) Total mass and momentum are therefore conserved exactly, walls or not.
    """
    d = pos.shape[1]
    support = 2.0 * kp[1]
    for i in range(ptr.size - 1):
        if kind[i] != 0:  # solid rows keep their fields
            continue
        sv = 0.0
        sm = 0.0
        p0 = p1 = p2 = 0.0
        si0 = step[i, 0]
        si1 = step[i, 1] if d > 1 else 0.0
        si2 = step[i, 2] if d > 2 else 0.0
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            x0, x1, x2, r = pair(pos, i, j, d)
            if r >= support:
                continue
            s = kernel_f(r, kp) * vol[j]
            w0, w1, w2 = s * x0, s * x1, s * x2
            if solid(kind[j]):  # the mirrored step's volume term only: s_j - s_i = -2 (s_i . n_j) n_j
                n0 = normal[j, 0]
                n1 = normal[j, 1] if d > 1 else 0.0
                n2 = normal[j, 2] if d > 2 else 0.0
                sv -= 2.0 * (si0 * n0 + si1 * n1 + si2 * n2) * (n0 * w0 + n1 * w1 + n2 * w2)
                continue
            sj0 = step[j, 0]
            sj1 = step[j, 1] if d > 1 else 0.0
            sj2 = step[j, 2] if d > 2 else 0.0
            rho_j = rho[j]
            uj0 = vel[j, 0]
            uj1 = vel[j, 1] if d > 1 else 0.0
            uj2 = vel[j, 2] if d > 2 else 0.0
            fj = sj0 * w0 + sj1 * w1 + sj2 * w2
            fi = si0 * w0 + si1 * w1 + si2 * w2
            sv += fj - fi
            sm += rho[i] * fi + rho_j * fj
            p0 += rho[i] * vel[i, 0] * fi + rho_j * uj0 * fj
            if d > 1:
                p1 += rho[i] * vel[i, 1] * fi + rho_j * uj1 * fj
            if d > 2:
                p2 += rho[i] * vel[i, 2] * fi + rho_j * uj2 * fj
        d_vol[i] = vol[i] * sv
        d_mass[i] = vol[i] * sm
        d_mom[i, 0] = vol[i] * p0
        if d > 1:
            d_mom[i, 1] = vol[i] * p1
        if d > 2:
            d_mom[i, 2] = vol[i] * p2


@njit(cache=True)
def _monomials(x, h, order, d, out):
    """(1, x/h, [quadratic terms]) for one displacement x."""
    out[0] = 1.0
    k = 1
    for a in range(d):
        out[k] = x[a] / h
        k += 1
    if order == 2:
        for a in range(d):
            for b in range(a, d):
                out[k] = x[a] * x[b] / (h * h)
                k += 1
    return k


@njit(cache=True)
def _solve_first(a, b, out_row, pivot_tol):
    """Row 0 of a^-1 b for a symmetric positive semi-definite a (Gaussian elimination without pivoting,
    which suffices for such matrices). Returns False if a pivot falls below pivot_tol x a[0, 0]."""
    m = a.shape[0]
    nf = b.shape[1]
    scale = a[0, 0]
    for c in range(m):
        piv = a[c, c]
        if piv <= pivot_tol * scale:
            return False
        for r in range(c + 1, m):
            f = a[r, c] / piv
            if f != 0.0:
                for q in range(c, m):
                    a[r, q] -= f * a[c, q]
                for q in range(nf):
                    b[r, q] -= f * b[c, q]
    for q in range(nf):  # back substitution, keeping only the first unknown
        x = np.empty(m)
        for r in range(m - 1, -1, -1):
            s = b[r, q]
            for c in range(r + 1, m):
                s -= a[r, c] * x[c]
            x[r] = s / a[r, r]
        out_row[q] = x[0]
    return True


@njit(cache=True)
def mls_interpolate(new_pos, old_pos, old_vol, old_fields, ptr, idx, kp, order, out):
    """MLS reconstruction (order 1 or 2) of the columns of old_fields at new_pos (rows of ptr/idx index
    old particles). Falls back to first order, then to the Shepard average, where the moment matrix is
    singular (too few neighbours)."""
    d = new_pos.shape[1]
    h = kp[1]
    nf = old_fields.shape[1]
    size = 1 + d + (d * (d + 1) // 2 if order == 2 else 0)
    mono = np.empty(size)
    xij = np.empty(d)
    for i in range(ptr.size - 1):
        for ord_try in range(order, -1, -1):
            m = 1 + d + (d * (d + 1) // 2 if ord_try == 2 else 0) if ord_try > 0 else 1
            a = np.zeros((m, m))
            b = np.zeros((m, nf))
            for k in range(ptr[i], ptr[i + 1]):
                j = idx[k]
                r2 = 0.0
                for c in range(d):
                    xij[c] = new_pos[i, c] - old_pos[j, c]
                    r2 += xij[c] * xij[c]
                w = kernel_w(np.sqrt(r2), kp) * old_vol[j]
                if w == 0.0:
                    continue
                if ord_try == 0:
                    mono[0] = 1.0
                else:
                    _monomials(xij, h, ord_try, d, mono)
                for p in range(m):
                    for q in range(m):
                        a[p, q] += w * mono[p] * mono[q]
                    for f in range(nf):
                        b[p, f] += w * mono[p] * old_fields[j, f]
            if a[0, 0] <= 0.0:
                for f in range(nf):
                    out[i, f] = np.nan
                break
            if ord_try == 0:
                for f in range(nf):
                    out[i, f] = b[0, f] / a[0, 0]
                break
            if _solve_first(a, b, out[i], 1e-10):
                break
