"""Right-hand sides of the delta-ALE-SPH family (numba; seed 001 = Antuono et al. 2021).

Operators (seed 001 eq. 11-12), with grad_i W_ij = f(r) x_ij (compute.smoothing), x_ji = x_j - x_i:
    <div u>_i          = sum_j (u_j - u_i) . grad_i W_ij V_j
    <grad p>_i         = sum_j (p_j + p_i) grad_i W_ij V_j        ((p_j - p_i) where p_i < 0: tensile switch)
    <div V>_i          = mu sum_j pi_ij grad_i W_ij V_j,  pi_ij = K (u_j - u_i) . x_ji / |x_ji|^2,  K = 2 (d + 2)
                         (morris = True: mu sum_j 2 (u_j - u_i) F_ij V_j, F_ij below; Morris, Fox and Zhu 1997, J.
                         Comput. Phys. 136, with constant mu and rho: the Laplacian alone, without
                         eq. 11's 2 grad div u, and with no lattice anisotropy, see tests/compute/test_fluid.py)
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
Two passes per right-hand side: renormalised_gradient visits the neighbour lists (with their skin) and also
writes the pairs inside the kernel support with their f(r) to a PairCache (and, for a shifting law, the
corrected grad C); delta_ale_rhs then loops over
those pairs only, without a distance test or a kernel evaluation (2.5x faster than over the lists).
"""

import numpy as np
from numba import njit

from psph.compute.jit import per_dimension
from psph.compute.shift_velocity import grad_c_weight
from psph.compute.smoothing import kernel_f
from psph.compute.sums import dot, load, pair2, solid, solve_symmetric, store


def _compile(d):
    """The two kernels for dimension d. d is a compile-time constant of each closure, so every 3-D (or 2-D)
    term below sits behind a condition that numba removes for lower dimensions: a 2-D run computes no
    padded zero components."""

    @per_dimension(d)
    def renormalised_gradient(pos, vol, phi, ptr, idx, kp, kind, fluid_only, out, with_gradient, cptr, cidx, cf,
                              with_grad_c, coeff, power, w_ref, grad_c):
        """The renormalised gradient of phi (with_gradient) with the pair cache (see the wrapper below) and,
        with_grad_c, in the same pass over the lists, compute.shift_velocity's corrected grad C of every row
        over every neighbour (solids included), in the same sums and order as corrected_grad_c (the same
        bits), but for a solid's rows with fluid_only: they are skipped, their grad C zero (no law moves a
        solid)."""
        s2 = 4.0 * kp[1] * kp[1]
        c = 0
        for i in range(ptr.size - 1):
            m00 = m01 = m02 = m11 = m12 = m22 = 0.0
            g0 = g1 = g2 = 0.0
            c0_ = c1_ = c2_ = 0.0
            row = not (fluid_only and solid(kind[i]))  # inflow rows too: their neighbours read it
            if not row:  # a solid's row: no field, and the shifting laws zero its grad C (its shift velocity)
                cptr[i + 1] = c
                if with_grad_c:
                    store(grad_c, i, d, 0.0, 0.0, 0.0)
                continue
            for k in range(ptr[i], ptr[i + 1]):
                j = idx[k]
                x0, x1, x2, rr = pair2(pos, i, j, d)
                if rr >= s2:  # beyond the support: nothing in either sum (f = 0 there)
                    continue
                r = np.sqrt(rr)
                f = kernel_f(r, kp)
                if with_grad_c:
                    sc = grad_c_weight(r, f, vol[j], kp, coeff, power, w_ref)
                    c0_ += sc * x0
                    if d > 1:
                        c1_ += sc * x1
                    if d > 2:
                        c2_ += sc * x2
                if fluid_only and solid(kind[j]):
                    continue
                s = f * vol[j]
                cidx[c] = j
                cf[c] = f
                c += rr > 0.0
                if not with_gradient:
                    continue
                m00 -= s * x0 * x0
                dphi = s * (phi[j] - phi[i])
                g0 += dphi * x0
                if d > 1:
                    m01 -= s * x0 * x1
                    m11 -= s * x1 * x1
                    g1 += dphi * x1
                if d > 2:
                    m02 -= s * x0 * x2
                    m12 -= s * x1 * x2
                    m22 -= s * x2 * x2
                    g2 += dphi * x2
            cptr[i + 1] = c
            if with_grad_c:
                store(grad_c, i, d, c0_, c1_, c2_)
            if not with_gradient:
                continue
            r0, r1, r2 = solve_symmetric(m00, m01, m02, m11, m12, m22, g0, g1, g2, d, 1e-6)
            store(out, i, d, r0, r1, r2)

    @per_dimension(d)
    def delta_ale_rhs(pos, vol, rho, mass, vel, du, prs, grad_rho, ptr, idx, cf, h, c0, delta, delta_m, mu,
                      morris, gravity, variant, with_shift, tensile_switch, diffusive, kind, fluid_only, d_rho,
                      d_mass, d_mom):
        kk = 2.0 * (d + 2)
        c_rho = 2.0 * delta * h * c0
        c_m = 2.0 * delta_m * h * c0
        use_dm = variant == 0 and delta_m > 0.0
        sqrt_vol = np.sqrt(vol) if use_dm else vol
        g0_ = gravity[0]
        g1_ = gravity[1] if d > 1 else 0.0
        g2_ = gravity[2] if d > 2 else 0.0
        for i in range(ptr.size - 1):
            if fluid_only and kind[i] != 0:
                d_rho[i] = 0.0
                d_mass[i] = 0.0
                store(d_mom, i, d, 0.0, 0.0, 0.0)
                continue
            ui0, ui1, ui2 = load(vel, i, d)
            di0 = di1 = di2 = 0.0
            if with_shift:
                di0, di1, di2 = load(du, i, d)
            gi0, gi1, gi2 = load(grad_rho, i, d)
            rho_i = rho[i]
            p_i = prs[i]
            switch = tensile_switch[i] != 0 and p_i < 0.0
            diffuse_i = diffusive[i] != 0
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
                x0, x1, x2, rr = pair2(pos, i, j, d)
                f = cf[k]
                vj = vol[j]
                fv = f * vj
                w0, w1, w2 = fv * x0, fv * x1, fv * x2  # grad_i W_ij V_j
                uj0, uj1, uj2 = load(vel, j, d)
                dux, duy, duz = uj0 - ui0, uj1 - ui1, uj2 - ui2
                # pressure
                pp = prs[j] - p_i if switch else prs[j] + p_i
                div_u += dot(dux, duy, duz, w0, w1, w2, d)
                gp0 += pp * w0
                if d > 1:
                    gp1 += pp * w1
                if d > 2:
                    gp2 += pp * w2
                if morris:  # 2 (u_j - u_i) F_ij V_j = -2 f V_j (u_j - u_i)
                    vs0 -= 2.0 * fv * dux
                    if d > 1:
                        vs1 -= 2.0 * fv * duy
                    if d > 2:
                        vs2 -= 2.0 * fv * duz
                else:  # pi_ij = K (u_j - u_i) . x_ji / r^2, x_ji = -x_ij
                    pi = -kk * dot(dux, duy, duz, x0, x1, x2, d) / rr
                    vs0 += pi * w0
                    if d > 1:
                        vs1 += pi * w1
                    if d > 2:
                        vs2 += pi * w2
                # diffusive terms: F_ij = -f; on a pair only where both particles take part (antisymmetric)
                if diffuse_i and diffusive[j] != 0:
                    gj0, gj1, gj2 = load(grad_rho, j, d)
                    psi = (rho[j] - rho_i) + 0.5 * dot(gi0 + gj0, gi1 + gj1, gi2 + gj2, x0, x1, x2, d)
                    diff_rho -= psi * fv
                    if use_dm:
                        diff_m -= (mass[j] - mass[i]) * f * sqrt_vol[j]
                if with_shift:
                    dj0, dj1, dj2 = load(du, j, d)
                    div_du += dot(dj0 - di0, dj1 - di1, dj2 - di2, w0, w1, w2, d)
                    ddj = dot(dj0, dj1, dj2, w0, w1, w2, d)  # du_j . grad W V_j
                    ddi = dot(di0, di1, di2, w0, w1, w2, d)
                    rho_j = rho[j]
                    div_rdu += rho_j * ddj + rho_i * ddi
                    if variant == 0:  # div(rho u x du)
                        cj, ci = rho_j * ddj, rho_i * ddi
                    else:  # div(u x du) - u_i div(du) is assembled below
                        cj, ci = ddj, ddi
                    sh0 += uj0 * cj + ui0 * ci
                    if d > 1:
                        sh1 += uj1 * cj + ui1 * ci
                    if d > 2:
                        sh2 += uj2 * cj + ui2 * ci
            d_rho[i] = -rho_i * (div_u + div_du) + div_rdu + c_rho * diff_rho
            if variant == 0:
                vi = vol[i]
                mi = mass[i]
                d_mass[i] = vi * div_rdu + (c_m * diff_m * sqrt_vol[i] if use_dm else 0.0)
                store(d_mom, i, d, vi * (-gp0 + mu * vs0 + sh0) + mi * g0_, vi * (-gp1 + mu * vs1 + sh1) + mi * g1_,
                      vi * (-gp2 + mu * vs2 + sh2) + mi * g2_)
            else:
                store(d_mom, i, d, (-gp0 + mu * vs0) / rho_i + g0_ + sh0 - ui0 * div_du,
                      (-gp1 + mu * vs1) / rho_i + g1_ + sh1 - ui1 * div_du,
                      (-gp2 + mu * vs2) / rho_i + g2_ + sh2 - ui2 * div_du)

    return renormalised_gradient, delta_ale_rhs


_KERNELS = {d: _compile(d) for d in (1, 2, 3)}


class PairCache:
    """The pairs inside the kernel support (r > 0) of each row, with f(r): CSR ptr, idx and f, filled by
    renormalised_gradient and read by delta_ale_rhs. Sized for a set of neighbour lists (reallocated when
    they grow)."""

    def __init__(self):
        self.ptr = np.zeros(1, dtype=np.int64)
        self.idx = np.zeros(0, dtype=np.int32)
        self.f = np.zeros(0)

    def fit(self, ptr, idx):
        """Room for every pair of the lists (ptr, idx)."""
        if self.ptr.size != ptr.size:
            self.ptr = np.zeros(ptr.size, dtype=np.int64)
        if self.idx.size < idx.size:
            self.idx = np.empty(idx.size, dtype=np.int32)
            self.f = np.empty(idx.size)
        return self


def renormalised_gradient(pos, vol, phi, ptr, idx, kp, kind, fluid_only, out, pairs=None, grad_c=None,
                          gradient=True):
    """<grad phi>^L_i = L_i sum_j (phi_j - phi_i) grad_i W_ij V_j (seed 001 eq. 15), fused in one pass, for
    the rows of ptr. fluid_only: sum over fluid and inflow particles only (not solids), and only for their
    rows (walls carry no field; an inflow particle's gradient enters its fluid neighbours'
    D^rho). pairs: a PairCache to fill with the
    summed pairs inside the support (for delta_ale_rhs).
    grad_c = (coeff, power, w_ref, g): also fill g (rows of ptr) with the corrected grad C of
    compute.shift_velocity.corrected_grad_c in the same pass (the same values, one walk of the lists; zero
    in a solid's rows with fluid_only, which are skipped: the shifting laws move fluid only).
    Pairs beyond the support are skipped (f = 0 there, but for pairs within rounding of its edge, whose
    f of order 1e-42 the gradient left out as well). gradient = False: only the pair cache (and grad C),
    out untouched (a scheme without diffusive terms reads no density gradient)."""
    pairs = (pairs or PairCache()).fit(ptr, idx)
    coeff, power, w_ref, g = grad_c if grad_c is not None else (0.0, 1.0, 1.0, np.zeros((0, pos.shape[1])))
    _KERNELS[pos.shape[1]][0](pos, vol, phi, ptr, idx, kp, kind, fluid_only, out, bool(gradient), pairs.ptr,
                              pairs.idx, pairs.f, grad_c is not None, float(coeff), float(power), float(w_ref), g)


def delta_ale_rhs(pos, vol, rho, mass, vel, du, prs, grad_rho, pairs, kp, c0, delta, delta_m, mu,
                  gravity, variant, with_shift, tensile_switch, kind, fluid_only, d_rho, d_mass, d_mom,
                  morris=False, diffusive=True):
    """Time derivatives of the owned particles (rows of pairs) for the delta-ALE-SPH family.

    pairs: the PairCache that renormalised_gradient filled at the same positions (with the same kind and
    fluid_only). variant 0: d_rho, d_mass, d_mom = d(m u)/dt (seed 001 eq. 13); 1 and 2: d_rho and
    d_mom = du/dt (eq. 23 and 25; d_mass untouched). vol holds the operators' volumes (V = m / rho, or V0
    for variant 2). with_shift = False skips every du-term (du is then not read). delta_m = 0 switches D^m
    off. fluid_only: fluid rows only (the walls' pairs: psph.compute.walls). morris: Morris' viscous
    operator instead of seed 001 eq. 11. tensile_switch: int8 per particle, 1 where p_j - p_i replaces
    p_j + p_i when p_i < 0 (seed 004 eq. 3: not in the free-surface region), or a bool for all of them.
    diffusive: int8 per particle, 1 where it takes part in D^rho and D^m (a pair diffuses where both do: seed
    001 section 6.3), or a bool for all of them.
    """
    _KERNELS[pos.shape[1]][1](pos, vol, rho, mass, vel, du, prs, grad_rho, pairs.ptr, pairs.idx, pairs.f, kp[1],
                              c0, delta, delta_m, mu, morris, gravity, variant, with_shift,
                              switch_rows(tensile_switch, len(pos)), switch_rows(diffusive, len(pos)), kind,
                              fluid_only, d_rho, d_mass, d_mom)


def switch_rows(switch, n) -> np.ndarray:
    """A switch per particle (int8): the array given, or a bool for all n particles."""
    if isinstance(switch, np.ndarray):
        return switch
    return np.full(n, int(bool(switch)), dtype=np.int8)


@njit(cache=True)
def fluid_momentum_totals(kind, mass, vel, d_mom, rates_are_momentum, out):
    """out = [sum of d(m u)/dt (d entries), sum of m u (d entries), sum of m] over the owned fluid rows
    (kind 0) of d_mom. rates_are_momentum: d_mom holds d(m u)/dt (delta-ALE-SPH), else du/dt (the variants,
    whose rate is m du/dt)."""
    d = vel.shape[1]
    out[:] = 0.0
    for i in range(d_mom.shape[0]):
        if kind[i] != 0:
            continue
        m = mass[i]
        for a in range(d):
            out[a] += d_mom[i, a] if rates_are_momentum else m * d_mom[i, a]
            out[d + a] += m * vel[i, a]
        out[2 * d] += m


@njit(cache=True)
def add_uniform_acceleration(kind, mass, g, rates_are_momentum, d_mom):
    """d_mom_i += m_i g (momentum rates) or g (velocity rates) on the owned fluid rows."""
    for i in range(d_mom.shape[0]):
        if kind[i] != 0:
            continue
        scale = mass[i] if rates_are_momentum else 1.0
        for a in range(d_mom.shape[1]):
            d_mom[i, a] += scale * g[a]
