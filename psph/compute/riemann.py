"""Right-hand side of the Riemann SPH-ALE scheme (numba; thesis 000 = Rastelli 2022, section 5.5).

Thesis eq. 5.48 (the form solved in ASPHODEL), with omega = V, grad_i W_ij = f(r) x_ij, x_ij = x_i - x_j:
    d x_i / dt         = v0_i
    d V_i / dt         = V_i sum_j 2 (v0_ij - v0_i) . grad_i W_ij V_j          v0_ij = (v0_i + v0_j) / 2 (eq. 5.43)
    d (V rho)_i / dt   = -V_i sum_j 2 rho^E (v^E - v0_ij) . grad_i W_ij V_j
    d (V rho v)_i / dt = -V_i sum_j 2 [rho^E v^E (v^E - v0_ij) . grad_i W_ij + p^E grad_i W_ij] V_j + m_i g
                         + V_i mu <lap v>_i   (the viscous operator of the delta-ALE family: eq. 11 or Morris')
(rho^E, v^E, p^E): the solution of the Riemann problem between the states reconstructed at the pair's
midpoint by MUSCL with the minmod limiter (eq. 5.49): with e = (x_j - x_i) / r and the renormalised
gradients (seed 001 eq. 15) of rho and of each velocity component, a_i = grad q_i . (x_j - x_i),
    q_L = q_i + minmod(a_i, q_j - q_i) / 2,   q_R = q_j - minmod(a_j, q_j - q_i) / 2
(alpha of eq. 5.49 = minmod(a, b) / a in [0, 1]; physics.muscl_limiter = "none": a_i and a_j themselves).
The thesis names no Riemann solver; psph uses the linearised (acoustic) one along e, Toro's primitive-
variable solver PVRS ("Riemann solvers and numerical methods for fluid dynamics", ch. 9), with u = v . e,
z = rho_bar c(rho_bar):
    u^E = (u_L + u_R) / 2 + (p_L - p_R) / (2 z),   p^E = (p_L + p_R) / 2 + z (u_L - u_R) / 2,
    rho^E = EOS^-1(p^E),   v^E = (v_L + v_R) / 2 + (u^E - (u_L + u_R) / 2) e;
physics.riemann_dissipation = "low" takes p^E from low_dissipation_pressure (Zhang, Hu and Adams 2017) in
the momentum flux, keeping the acoustic (rho^E, u^E) in the mass flux.
The interface state is the same seen from i or from j (swapping i and j reverses e and swaps L and R),
and the fluxes carry +-grad_i W_ij, so mass and momentum are conserved pair by pair
(tests/compute/test_riemann.py); with equal left and right states the solver returns that state and the
fluxes are the centred SPH-ALE ones (eq. 5.45 with F_ij = (F_i + F_j) / 2).
"""

import numpy as np
from numba import njit

from psph.compute.eos import density, pressure, sound_speed
from psph.compute.jit import per_dimension
from psph.compute.sums import pair2, solid, solve_symmetric


@njit(cache=True, inline="always")
def minmod(a, b):
    """minmod(a, b): the smaller in magnitude if a and b have the same sign, else 0."""
    if a * b <= 0.0:
        return 0.0
    return a if abs(a) < abs(b) else b


@njit(cache=True, inline="always")
def _slope(a, b, limited):
    """The reconstruction's change over the pair: minmod(a, b) (limited), or the gradient's own a."""
    return minmod(a, b) if limited else a


@njit(cache=True)
def acoustic_riemann(rho_l, u_l, rho_r, u_r, c0, rho0, tait):
    """(rho^E, u^E, p^E) of the linearised Riemann problem between (rho_l, u_l) and (rho_r, u_r), u the
    velocity component along the left-to-right axis: Toro's PVRS (ch. 9; the module's formulas), the
    interface state of thesis eq. 5.48's fluxes."""
    p_l = pressure(rho_l, c0, rho0, tait)
    p_r = pressure(rho_r, c0, rho0, tait)
    rho_bar = 0.5 * (rho_l + rho_r)
    z = rho_bar * sound_speed(rho_bar, c0, rho0, tait)
    u_s = 0.5 * (u_l + u_r) + 0.5 * (p_l - p_r) / z
    # particles separating faster than the states' pressures allow open a vacuum between them (Toro 2009,
    # ch. 4): p^E no lower than the equation of state's p(0), where rho^E = 0 (no NaN from Tait's root)
    p_s = max(0.5 * (p_l + p_r) + 0.5 * z * (u_l - u_r), pressure(0.0, c0, rho0, tait))
    return density(p_s, c0, rho0, tait), u_s, p_s


@njit(cache=True)
def low_dissipation_pressure(rho_l, u_l, rho_r, u_r, c0, rho0, tait):
    """p^E of Zhang, Hu and Adams (2017, J. Comput. Phys. 335): the acoustic solver's dissipation
    z (u_L - u_R) / 2 with the sound speed replaced by beta = min(3 max(u_L - u_R, 0), c): none where the
    particles separate, and second order in the jump where they approach. (Zhang et al. average p and rho
    weighted by the other side's density; psph takes the plain means, which agree to first order in the
    density jump.) Never below p(0): the states' mean is not, and the dissipation adds only where they
    approach."""
    rho_bar = 0.5 * (rho_l + rho_r)
    c = sound_speed(rho_bar, c0, rho0, tait)
    beta = min(3.0 * max(u_l - u_r, 0.0), c)
    return 0.5 * (pressure(rho_l, c0, rho0, tait) + pressure(rho_r, c0, rho0, tait)) + 0.5 * rho_bar * beta * (
        u_l - u_r)


def _compile(d):
    @per_dimension(d)
    def velocity_gradient(pos, vol, vel, ptr, idx, cf, out):
        """out[i, a, b] = (L_i sum_j (v_j - v_i)_a grad_i W_ij V_j)_b over the cached pairs (seed 001 eq. 15)."""
        g = np.zeros((3, 3))
        x = np.zeros(3)
        for i in range(ptr.size - 1):
            m00 = m01 = m02 = m11 = m12 = m22 = 0.0
            g[:, :] = 0.0
            for k in range(ptr[i], ptr[i + 1]):
                j = idx[k]
                s = cf[k] * vol[j]
                x[0], x[1], x[2], _ = pair2(pos, i, j, d)
                m00 -= s * x[0] * x[0]
                if d > 1:
                    m01 -= s * x[0] * x[1]
                    m11 -= s * x[1] * x[1]
                if d > 2:
                    m02 -= s * x[0] * x[2]
                    m12 -= s * x[1] * x[2]
                    m22 -= s * x[2] * x[2]
                for a in range(d):
                    dv = s * (vel[j, a] - vel[i, a])
                    for b in range(d):
                        g[a, b] += dv * x[b]
            for a in range(d):
                r = solve_symmetric(m00, m01, m02, m11, m12, m22, g[a, 0], g[a, 1], g[a, 2], d, 1e-6)
                for b in range(d):
                    out[i, a, b] = r[b]

    @per_dimension(d)
    def riemann_ale_rhs(pos, vol, rho, mass, vel, v0, grad_rho, grad_vel, ptr, idx, cf, c0, rho0, tait, mu,
                        morris, limited, low, gravity, kind, fluid_only, d_vol, d_mass, d_mom):
        kk = 2.0 * (d + 2)
        x = np.zeros(3)
        e = np.zeros(3)
        vl = np.zeros(3)
        vr = np.zeros(3)
        v_s = np.zeros(3)
        mom = np.zeros(3)
        visc = np.zeros(3)
        for i in range(ptr.size - 1):
            if fluid_only and solid(kind[i]):  # a solid's state is its body's (zero rates)
                continue
            acc_v = 0.0
            acc_m = 0.0
            mom[:] = 0.0
            visc[:] = 0.0
            for k in range(ptr[i], ptr[i + 1]):
                j = idx[k]
                x[0], x[1], x[2], rr = pair2(pos, i, j, d)
                r = np.sqrt(rr)
                fv = cf[k] * vol[j]
                # MUSCL reconstruction at the midpoint (x_j - x_i = -x)
                a_i = 0.0
                a_j = 0.0
                for b in range(d):
                    a_i -= grad_rho[i, b] * x[b]
                    a_j -= grad_rho[j, b] * x[b]
                jump = rho[j] - rho[i]
                rho_l = rho[i] + 0.5 * _slope(a_i, jump, limited)
                rho_r = rho[j] - 0.5 * _slope(a_j, jump, limited)
                u_l = 0.0
                u_r = 0.0
                for a in range(d):
                    e[a] = -x[a] / r
                    a_i = 0.0
                    a_j = 0.0
                    for b in range(d):
                        a_i -= grad_vel[i, a, b] * x[b]
                        a_j -= grad_vel[j, a, b] * x[b]
                    jump = vel[j, a] - vel[i, a]
                    vl[a] = vel[i, a] + 0.5 * _slope(a_i, jump, limited)
                    vr[a] = vel[j, a] - 0.5 * _slope(a_j, jump, limited)
                    u_l += vl[a] * e[a]
                    u_r += vr[a] * e[a]
                rho_s, u_s, p_s = acoustic_riemann(rho_l, u_l, rho_r, u_r, c0, rho0, tait)
                if low:
                    p_s = low_dissipation_pressure(rho_l, u_l, rho_r, u_r, c0, rho0, tait)
                du_n = u_s - 0.5 * (u_l + u_r)
                q = 0.0  # (v^E - v0_ij) . 2 grad_i W_ij V_j
                for a in range(d):
                    v_s[a] = 0.5 * (vl[a] + vr[a]) + du_n * e[a]
                    q += (v_s[a] - 0.5 * (v0[i, a] + v0[j, a])) * 2.0 * fv * x[a]
                    acc_v += (v0[j, a] - v0[i, a]) * fv * x[a]
                acc_m -= rho_s * q
                dvx = 0.0
                for a in range(d):
                    mom[a] -= rho_s * v_s[a] * q + p_s * 2.0 * fv * x[a]
                    dvx += (vel[j, a] - vel[i, a]) * x[a]
                for a in range(d):  # the delta-ALE family's viscous operators (psph.compute.fluid)
                    if morris:
                        visc[a] -= 2.0 * fv * (vel[j, a] - vel[i, a])
                    else:
                        visc[a] -= kk * dvx / rr * fv * x[a]
            vi = vol[i]
            d_vol[i] = vi * acc_v
            d_mass[i] = vi * acc_m
            for a in range(d):
                d_mom[i, a] = vi * (mom[a] + mu * visc[a]) + mass[i] * gravity[a]

    return velocity_gradient, riemann_ale_rhs


_KERNELS = {d: _compile(d) for d in (1, 2, 3)}


def velocity_gradient(pos, vol, vel, pairs, out):
    """Renormalised gradient of every velocity component, out[i, a, b] = d v_a / d x_b, for the rows of
    pairs (a PairCache filled at these positions)."""
    _KERNELS[pos.shape[1]][0](pos, vol, vel, pairs.ptr, pairs.idx, pairs.f, out)


def riemann_ale_rhs(pos, vol, rho, mass, vel, v0, grad_rho, grad_vel, pairs, c0, rho0, tait, mu, morris,
                    gravity, d_vol, d_mass, d_mom, limited=True, low_dissipation=False, kind=None):
    """dV/dt, dm/dt and d(m v)/dt of the rows of pairs (thesis eq. 5.48; module docstring). v0: the
    transport velocities of all local particles; grad_rho, grad_vel: renormalised gradients of all local
    particles (halo included); gravity: a d-vector; limited = False: MUSCL without the minmod limiter.
    kind (with walls, whose pairs psph.compute.walls adds): the solids' rows are left at zero (pairs filled
    with fluid_only holds no solid neighbour)."""
    fluid_only = kind is not None
    _KERNELS[pos.shape[1]][1](pos, vol, rho, mass, vel, v0, grad_rho, grad_vel, pairs.ptr, pairs.idx, pairs.f,
                              c0, rho0, tait, mu, morris, limited, low_dissipation,
                              np.asarray(gravity, dtype=np.float64),
                              kind if fluid_only else np.zeros(0, dtype=np.int8), fluid_only, d_vol, d_mass, d_mom)
