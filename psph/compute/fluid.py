"""Right-hand sides of the delta-ALE-SPH family (numba; seed 001 = Antuono et al. 2021).

Operators (seed 001 eq. 11-12), with grad_i W_ij = f(r) x_ij (compute.smoothing), x_ji = x_j - x_i:
    <div u>_i          = sum_j (u_j - u_i) . grad_i W_ij V_j
    <grad p>_i         = sum_j (p_j + p_i) grad_i W_ij V_j        ((p_j - p_i) where p_i < 0: tensile switch)
    <div V>_i          = mu sum_j pi_ij grad_i W_ij V_j,  pi_ij = K (u_j - u_i) . x_ji / |x_ji|^2,  K = 2 (d + 2)
    <div du>_i         = sum_j (du_j - du_i) . grad_i W_ij V_j
    <div(rho du)>_i    = sum_j (rho_j du_j + rho_i du_i) . grad_i W_ij V_j
    <div(rho u x du)>_i = sum_j (rho_j u_j (du_j . grad_i W_ij) + rho_i u_i (du_i . grad_i W_ij)) V_j
Diffusive terms (eq. 14) with F_ij = x_ji . grad_i W_ij / |x_ji|^2 = -f(r):
    D^rho_i = 2 delta h c0 sum_j psi_ji F_ij V_j,
    psi_ji  = (rho_j - rho_i) - (<grad rho>^L_i + <grad rho>^L_j) . x_ji / 2
    D^m_i   = 2 delta_m h c0 sum_j (m_j - m_i) F_ij sqrt(V_i V_j)
Renormalised gradient (eq. 15, index misprint corrected): <grad rho>^L_i = L_i sum_j (rho_j - rho_i) grad_i W_ij V_j,
L_i = [sum_j x_ji (x) grad_i W_ij V_j]^-1 (identity where that matrix is near-singular).

Variants (`variant`): 0 delta-ALE-SPH (eq. 13: rho, m and m u evolve), 1 constant mass (eq. 23: rho and u;
V = m / rho), 2 constant volume (eq. 25: rho and u; the operators use the initial volumes V0, m = V0 rho).
Pairs beyond the kernel support (the neighbour lists' skin) are skipped.
"""

import numpy as np
from numba import njit

from psph.compute.smoothing import kernel_f
from psph.compute.sums import pair


@njit(cache=True)
def _solve_sym(m00, m01, m02, m11, m12, m22, g0, g1, g2, d, tol):
    """x = M^-1 g for a symmetric d x d M (g itself where M is near-singular: no renormalisation)."""
    if d == 1:
        if m00 > tol:
            return g0 / m00, 0.0, 0.0
        return g0, 0.0, 0.0
    if d == 2:
        det = m00 * m11 - m01 * m01
        if det > tol * tol:
            return (m11 * g0 - m01 * g1) / det, (m00 * g1 - m01 * g0) / det, 0.0
        return g0, g1, 0.0
    c00 = m11 * m22 - m12 * m12
    c01 = m02 * m12 - m01 * m22
    c02 = m01 * m12 - m02 * m11
    det = m00 * c00 + m01 * c01 + m02 * c02
    if det > tol * tol * tol:
        c11 = m00 * m22 - m02 * m02
        c12 = m01 * m02 - m00 * m12
        c22 = m00 * m11 - m01 * m01
        return ((c00 * g0 + c01 * g1 + c02 * g2) / det, (c01 * g0 + c11 * g1 + c12 * g2) / det,
                (c02 * g0 + c12 * g1 + c22 * g2) / det)
    return g0, g1, g2


@njit(cache=True)
def renormalised_gradient(pos, vol, phi, ptr, idx, kp, kind, fluid_only, out):
    """<grad phi>^L_i = L_i sum_j (phi_j - phi_i) grad_i W_ij V_j (seed 001 eq. 15), fused in one pass.
    fluid_only: sum over fluid particles (kind 0) only, and only for fluid rows (walls carry no field)."""
    d = pos.shape[1]
    support = 2.0 * kp[1]
    for i in range(ptr.size - 1):
        m00 = m01 = m02 = m11 = m12 = m22 = 0.0
        g0 = g1 = g2 = 0.0
        if fluid_only and kind[i] != 0:
            continue
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if fluid_only and kind[j] != 0:
                continue
            x0, x1, x2, r = pair(pos, i, j, d)
            if r >= support:
                continue
            s = kernel_f(r, kp) * vol[j]
            m00 -= s * x0 * x0
            m01 -= s * x0 * x1
            m02 -= s * x0 * x2
            m11 -= s * x1 * x1
            m12 -= s * x1 * x2
            m22 -= s * x2 * x2
            dphi = s * (phi[j] - phi[i])
            g0 += dphi * x0
            g1 += dphi * x1
            g2 += dphi * x2
        r0, r1, r2 = _solve_sym(m00, m01, m02, m11, m12, m22, g0, g1, g2, d, 1e-6)
        out[i, 0] = r0
        if d > 1:
            out[i, 1] = r1
        if d > 2:
            out[i, 2] = r2


@njit(cache=True)
def delta_ale_rhs(pos, vol, rho, mass, vel, du, prs, grad_rho, ptr, idx, kp, c0, delta, delta_m, mu,
                  gravity, variant, with_shift, tensile_switch, kind, fluid_only, d_rho, d_mass, d_mom):
    """Time derivatives of the owned particles (rows of ptr) for the delta-ALE-SPH family.

    variant 0: d_rho, d_mass, d_mom = d(m u)/dt (seed 001 eq. 13); 1 and 2: d_rho and d_mom = du/dt
    (eq. 23 and 25; d_mass untouched). vol holds the operators' volumes (V = m / rho, or V0 for variant 2).
    with_shift = False skips every du-term (du is then not read). delta_m = 0 switches D^m off.
    fluid_only: fluid-fluid pairs and fluid rows only (the walls' pairs: psph.compute.walls).
    """
    d = pos.shape[1]
    h = kp[1]
    support = 2.0 * h
    kk = 2.0 * (d + 2)
    c_rho = 2.0 * delta * h * c0
    c_m = 2.0 * delta_m * h * c0
    use_dm = variant == 0 and delta_m > 0.0
    sqrt_vol = np.sqrt(vol) if use_dm else vol
    for i in range(ptr.size - 1):
        if fluid_only and kind[i] != 0:
            d_rho[i] = 0.0
            d_mass[i] = 0.0
            for a in range(d):
                d_mom[i, a] = 0.0
            continue
        ui0 = vel[i, 0]
        ui1 = vel[i, 1] if d > 1 else 0.0
        ui2 = vel[i, 2] if d > 2 else 0.0
        di0 = di1 = di2 = 0.0
        if with_shift:
            di0 = du[i, 0]
            di1 = du[i, 1] if d > 1 else 0.0
            di2 = du[i, 2] if d > 2 else 0.0
        gi0 = grad_rho[i, 0]
        gi1 = grad_rho[i, 1] if d > 1 else 0.0
        gi2 = grad_rho[i, 2] if d > 2 else 0.0
        rho_i = rho[i]
        p_i = prs[i]
        switch = tensile_switch and p_i < 0.0
        div_u = 0.0
        div_du = 0.0
        div_rdu = 0.0
        diff_rho = 0.0
        diff_m = 0.0
        gp0 = gp1 = gp2 = 0.0
        vs0 = vs1 = vs2 = 0.0
        sh0 = sh1 = sh2 = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if fluid_only and kind[j] != 0:
                continue
            x0, x1, x2, r = pair(pos, i, j, d)
            if r >= support or r == 0.0:
                continue
            f = kernel_f(r, kp)
            vj = vol[j]
            w0 = f * x0 * vj  # grad_i W_ij V_j
            w1 = f * x1 * vj
            w2 = f * x2 * vj
            uj0 = vel[j, 0]
            uj1 = vel[j, 1] if d > 1 else 0.0
            uj2 = vel[j, 2] if d > 2 else 0.0
            dux = uj0 - ui0
            duy = uj1 - ui1
            duz = uj2 - ui2
            div_u += dux * w0 + duy * w1 + duz * w2
            # pressure
            pp = prs[j] - p_i if switch else prs[j] + p_i
            gp0 += pp * w0
            gp1 += pp * w1
            gp2 += pp * w2
            # viscosity: pi_ij = K (u_j - u_i) . x_ji / r^2, x_ji = -x_ij
            pi = -kk * (dux * x0 + duy * x1 + duz * x2) / (r * r)
            vs0 += pi * w0
            vs1 += pi * w1
            vs2 += pi * w2
            # diffusive terms: F_ij = -f
            rho_j = rho[j]
            gj0 = grad_rho[j, 0]
            gj1 = grad_rho[j, 1] if d > 1 else 0.0
            gj2 = grad_rho[j, 2] if d > 2 else 0.0
            psi = (rho_j - rho_i) + 0.5 * ((gi0 + gj0) * x0 + (gi1 + gj1) * x1 + (gi2 + gj2) * x2)
            diff_rho -= psi * f * vj
            if use_dm:
                diff_m -= (mass[j] - mass[i]) * f * sqrt_vol[j]
            if with_shift:
                dj0 = du[j, 0]
                dj1 = du[j, 1] if d > 1 else 0.0
                dj2 = du[j, 2] if d > 2 else 0.0
                div_du += (dj0 - di0) * w0 + (dj1 - di1) * w1 + (dj2 - di2) * w2
                ddj = dj0 * w0 + dj1 * w1 + dj2 * w2  # du_j . grad W V_j
                ddi = di0 * w0 + di1 * w1 + di2 * w2
                div_rdu += rho_j * ddj + rho_i * ddi
                if variant == 0:  # div(rho u x du)
                    sh0 += rho_j * uj0 * ddj + rho_i * ui0 * ddi
                    sh1 += rho_j * uj1 * ddj + rho_i * ui1 * ddi
                    sh2 += rho_j * uj2 * ddj + rho_i * ui2 * ddi
                else:  # div(u x du) - u_i div(du) is assembled below
                    sh0 += uj0 * ddj + ui0 * ddi
                    sh1 += uj1 * ddj + ui1 * ddi
                    sh2 += uj2 * ddj + ui2 * ddi
        d_rho[i] = -rho_i * (div_u + div_du) + div_rdu + c_rho * diff_rho
        if variant == 0:
            vi = vol[i]
            d_mass[i] = vi * div_rdu + (c_m * diff_m * sqrt_vol[i] if use_dm else 0.0)
            a0 = vi * (-gp0 + mu * vs0 + sh0) + mass[i] * gravity[0]
            a1 = vi * (-gp1 + mu * vs1 + sh1) + mass[i] * (gravity[1] if d > 1 else 0.0)
            a2 = vi * (-gp2 + mu * vs2 + sh2) + mass[i] * (gravity[2] if d > 2 else 0.0)
        else:
            a0 = (-gp0 + mu * vs0) / rho_i + gravity[0] + sh0 - ui0 * div_du
            a1 = (-gp1 + mu * vs1) / rho_i + (gravity[1] if d > 1 else 0.0) + sh1 - ui1 * div_du
            a2 = (-gp2 + mu * vs2) / rho_i + (gravity[2] if d > 2 else 0.0) + sh2 - ui2 * div_du
        d_mom[i, 0] = a0
        if d > 1:
            d_mom[i, 1] = a1
        if d > 2:
            d_mom[i, 2] = a2
