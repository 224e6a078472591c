"""Field updates after an IIPS correction (thesis 000 chapter 9; numba).

NFTS, the fictitious time step (eq. 9.5-9.7): with s_i = dx_i / N, one of the N sub-steps is
    V_i'        = V_i + V_i sum_j (s_j - s_i) . grad_i W_ij V_j
    (V rho)_i'  = (V rho)_i + V_i sum_j (rho_i s_i + rho_j s_j) . grad_i W_ij V_j
    (V rho u)_i' = (V rho u)_i + V_i sum_j (rho_i u_i (s_i . grad_i W_ij) + rho_j u_j (s_j . grad_i W_ij)) V_j
followed by x_i' = x_i + s_i. The thesis prints the mass and momentum lines with a minus sign; with the
grad_i W_ij its volume line uses, only the plus sign keeps a uniform state uniform where grad C = 0 (moving
a volume through fluid at rest gains the mass it sweeps: d(m) = rho dV); tests/compute/test_field_update.py
checks it and the exact conservation of total mass and momentum. Where grad C_i = sum_j grad_i W_ij V_j is
not zero, the mass line exceeds rho x the volume line by 2 rho V_i s_i . grad C_i, with either sign: the
displacement that IIPS computed to level C is the one whose flux misses it, so a call from a disordered
state changes a uniform density (at rest from sigma = 0.1 dx, one call moving particles up to 0.31 dx:
rho in [0.944, 1.013]; a field-update audit). psph warns when a flow with NFTS starts perturbed without
iips.pre_newton; the thesis itself calls the NFTS pressure "quite noisy" (section 10.1).

NFTS's accuracy (a field-update audit, 2026-11-30): with a uniform rho the momentum line changes u_i by
sum_j (u_j - u_i) s_j . grad_i W_ij V_j, which its neighbours' displacements drive, not its own; so NFTS is
first order on a disordered set, and for displacements that are not smooth (IIPS's) no better than no update
(random 0.1 dx shifts in 2-D: L2 5.25e-3 against 5.00e-3). Swapping s_i and s_j in the momentum flux would
conserve as exactly and give s_i . grad u_i (3.1e-4), but it is not eq. 9.7, which psph keeps.

MLS re-interpolation (eq. 9.8 first order, 9.9 second order): for the new position x_i of a particle and
the old particles j around it, solve sum_j W_ij V_j P_ij P_ij^T a = sum_j phi_j W_ij V_j P_ij with
P_ij = (1, x_ij / h, ...) (the monomials up to the order) and take phi_i = a_0. (The thesis prints the
unknowns as (f, df/dx, ...); with x_ij = x_i - x_j they are (f, -h df/dx, ...), and eq. 9.9 lists five
unknowns of six, without d2f/dx2 and the 1/2 factors: only a_0 is read, which none of this changes.)
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
def _first_column_of_inverse(a, m, g, pivot_tol):
    """g = a^-1 e_0, which for a symmetric a is also row 0 of a^-1, for the m x m symmetric positive semi-definite
    a held in its upper triangle (overwritten). Gaussian elimination without pivoting, which suffices for such
    matrices, on the upper triangle only (each trailing block stays symmetric). Returns False if a pivot falls
    below pivot_tol x a[0, 0]."""
    scale = a[0, 0]
    for r in range(m):
        g[r] = 0.0
    g[0] = 1.0
    for c in range(m):
        piv = a[c, c]
        if piv <= pivot_tol * scale:
            return False
        for r in range(c + 1, m):
            f = a[c, r] / piv  # a[r, c], by symmetry
            if f != 0.0:
                for q in range(r, m):
                    a[r, q] -= f * a[c, q]
                g[r] -= f * g[c]
    for r in range(m - 1, -1, -1):
        s = g[r]
        for c in range(r + 1, m):
            s -= a[r, c] * g[c]
        g[r] = s / a[r, r]
    return True


# (on lattices and jittered boundaries at h/dx = 1.3-2: order 1 up to about 2, order 2 up to about 5, and 17
# half a dx past a jittered surface at h/dx = 1.3; the audit's nearly collinear supports: 35 to 1e7)
LEBESGUE_MAX = 20.0


@njit(cache=True)
def mls_interpolate(new_pos, old_pos, old_vol, old_fields, ptr, idx, kp, order, out):
    """MLS reconstruction (order 1 or 2) of the columns of old_fields at new_pos (rows of ptr/idx index
    old particles). Falls back to first order, then to the Shepard average, where the moment matrix is
    singular (too few neighbours) or the fit's Lebesgue constant sum_j |c_j| (c_j the weight of phi_j in
    phi_i; 1 for Shepard's) exceeds LEBESGUE_MAX: a nearly collinear support passed the pivot test and
    extrapolated an O(1) field to errors of 1.5-154 (a field-update audit); NaN where no old particle is
    within the support. Returns the number of particles fitted below `order` (the fallbacks, which the
    run's summary counts).

    With the moment matrix M = sum_j w_j P_j P_j^T (w_j = W_ij V_j) the fit is phi_i = e_0^T M^-1 sum_j w_j
    P_j phi_j = sum_j w_j (g . P_j) phi_j, g = M^-1 e_0 (M is symmetric): one solve per particle, whatever the
    number of fields, and M's upper triangle only."""
    d = new_pos.shape[1]
    h = kp[1]
    nf = old_fields.shape[1]
    size = 1 + d + (d * (d + 1) // 2 if order == 2 else 0)
    most = 0
    for i in range(ptr.size - 1):
        most = max(most, ptr[i + 1] - ptr[i])
    weight = np.empty(most)  # w_j of the neighbours within the support, their P_j and their numbers
    mono = np.empty((most, size))
    near = np.empty(most, dtype=np.int64)
    coef = np.empty(most)  # each neighbour's weight in the fit, c_j = w_j (g . P_j)
    a = np.empty((size, size))
    g = np.empty(size)
    xij = np.empty(d)
    fallbacks = 0
    for i in range(ptr.size - 1):
        n = 0
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            r2 = 0.0
            for c in range(d):
                xij[c] = new_pos[i, c] - old_pos[j, c]
                r2 += xij[c] * xij[c]
            w = kernel_w(np.sqrt(r2), kp) * old_vol[j]
            if w == 0.0:
                continue
            weight[n] = w
            near[n] = j
            # P_j = (1, x/h, [x_a x_b / h^2, a <= b]): a lower order's monomials are the first ones
            mono[n, 0] = 1.0
            for c in range(d):
                mono[n, 1 + c] = xij[c] / h
            if order == 2:
                u = 1 + d
                for c in range(d):
                    for e in range(c, d):
                        mono[n, u] = mono[n, 1 + c] * mono[n, 1 + e]
                        u += 1
            n += 1
        for f in range(nf):
            out[i, f] = np.nan
        for ord_try in range(order, -1, -1):
            m = 1 + d + (d * (d + 1) // 2 if ord_try == 2 else 0) if ord_try > 0 else 1
            for p in range(m):
                for q in range(p, m):
                    a[p, q] = 0.0
            for t in range(n):
                for p in range(m):
                    wp = weight[t] * mono[t, p]
                    for q in range(p, m):
                        a[p, q] += wp * mono[t, q]
            if a[0, 0] <= 0.0:  # no neighbour: NaN
                break
            if not _first_column_of_inverse(a, m, g, 1e-10):
                continue
            lebesgue = 0.0
            for t in range(n):
                c = 0.0
                for p in range(m):
                    c += g[p] * mono[t, p]
                coef[t] = c * weight[t]
                lebesgue += abs(coef[t])
            if lebesgue > LEBESGUE_MAX:  # a nearly singular support: the fit amplifies the data (Shepard's: 1)
                continue
            if ord_try < order:
                fallbacks += 1
            for f in range(nf):
                out[i, f] = 0.0
            for t in range(n):
                j = near[t]
                for f in range(nf):
                    out[i, f] += coef[t] * old_fields[j, f]
            break
    return fallbacks
