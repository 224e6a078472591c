"""Clone particles: the fluid-solid part of the delta-ALE-SPH right-hand side (seed 004 section III; numba).

For a fluid particle i and each solid particle j in its support, j takes values mirrored from i alone
(local mirroring). With n_i, s_i and u_b the normal, distance and body velocity of the body node closest
to i, and n_j, s_j the solid particle's normal and distance to the profile:

  normals (eq. 5)    n = n_i for every j if some solid neighbour has n_j . (x_i - x_j) > 0 (the fluid
                     particle lies behind that solid particle's wall, as at a corner's rear side),
                     else n = n_j; t = (-n_y, n_x). Eq. 5 prints n_j . (r_j - r_i), which, with normals
                     pointing out of the fluid as the paper orients them, holds for every ordinary wall
                     particle: all normals would be replaced and a corner's second wall would stop
                     repelling (tests/boundaries/test_clone.py)
  divergence (eq. 6) u_j.t = u_i.t,   u_j.n = [(u_b - u_i) s_j / max(s_i, ds) + u_b] . n
  Laplacian (eq. 7)  no slip:   u_j.t = [(u_b - u_i) s_j / max(s_i, ds) + u_b] . t,  u_j.n = u_i.n
                     free slip: u_j = u_i
  pressure (eq. 8-9) p_j = p_i + rho_i (g - a_j) . (x_j - x_i),  rho_j from the equation of state; eq. 8
                     keeps only the normal part, (g - a_j) . n (x_j - x_i) . n, which leaves a hydrostatic
                     column unbalanced along vertical walls (the clones would carry p_i at every height);
                     the two agree when g - a_j is normal to the wall
  pressure force     -sum_j (p_j + p_i) grad_i W_ij V_j, or (p_j - p_i) where p_i < 0 with the tensile
                     switch (seed 004 eq. 3: S_i sums over every neighbour, the clones included). With
                     the switch on the fluid pairs only, uniform suction p_j = p_i < 0 left the clones'
                     -2 p_i sum_j grad_i W_ij V_j, a pull of 2 |p_i| / rho_i per unit |sum| towards the wall
                     that dragged the moving square's wake particles through its rear corner. The force on
                     the body keeps the plus form (minus the plus-form force on the particle): the
                     physical pressure integral, suction included
  shifting           du_j = (du_i . t) t - (du_i . n) n   (du . n = 0 on the wall, seed 001 section 6.2)
with ds = dx / 4 (the body-node spacing). These pairs enter the continuity equation (divergence velocity,
shifting terms), the pressure and the viscous forces (Laplacian velocity); the diffusive terms D^rho and
D^m act between fluid particles only. The force of the walls on each fluid particle is accumulated per
body (pressure and viscous parts) for the body forces; the torque about the body centre too.
"""

import numpy as np
from numba import njit

from psph.compute.smoothing import kernel_f
from psph.compute.sums import pair


@njit(cache=True)
def near_wall_rows(kind, ptr, idx):
    """Owned fluid rows (kind 0) with at least one solid neighbour (kind != 0)."""
    out = np.zeros(ptr.size - 1, dtype=np.bool_)
    for i in range(ptr.size - 1):
        if kind[i] != 0:
            continue
        for k in range(ptr[i], ptr[i + 1]):
            if kind[idx[k]] != 0:
                out[i] = True
                break
    return np.flatnonzero(out)


@njit(cache=True)
def clone_rhs(pos, vol, rho, vel, du, prs, kind, body, normal, wall_dist, accel, wall_vel, rows, n_i_all, s_i_all,
              no_slip, ptr, idx, kp, c0, rho0, eos_b, eos_gamma, mu, gravity, ds_min, variant, with_shift,
              tensile_switch, centers, d_rho, d_mom, force, torque):
    """Add the solid neighbours' contributions to the owned fluid `rows` (2-D).

    n_i_all, s_i_all: the closest body node's normal and distance, per entry of rows; wall_vel: the velocity
    of each solid particle's own closest node (u_b of eq. 6-7; the same as the fluid particle's closest
    node's on a smooth rigid wall, and the consistent choice at the corners of a lid).
    no_slip: per body; eos_b > 0 selects Tait (p = eos_b ((rho/rho0)^gamma - 1)), else linear.
    tensile_switch: p_j - p_i instead of p_j + p_i in the particle's pressure force where p_i < 0 (eq. 3).
    force: (n_bodies, 2, 2) pressure and viscous force of the fluid on each body; torque: (n_bodies, 2).
    """
    support = 2.0 * kp[1]
    kk = 8.0  # K = 2 (d + 2), d = 2
    g0, g1 = gravity[0], gravity[1]
    for r in range(rows.size):
        i = rows[r]
        ni0, ni1 = n_i_all[r, 0], n_i_all[r, 1]
        si = max(s_i_all[r], ds_min)
        xi0, xi1 = pos[i, 0], pos[i, 1]
        ui0, ui1 = vel[i, 0], vel[i, 1]
        rho_i, p_i, v_i = rho[i], prs[i], vol[i]
        switch = tensile_switch and p_i < 0.0
        di0 = du[i, 0] if with_shift else 0.0
        di1 = du[i, 1] if with_shift else 0.0
        # eq. 5 (sign corrected): is the particle behind some solid particle's wall?
        use_own = False
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if kind[j] != 0 and normal[j, 0] * (xi0 - pos[j, 0]) + normal[j, 1] * (xi1 - pos[j, 1]) > 0.0:
                x0, x1, _, rr = pair(pos, i, j, 2)
                if rr < support:
                    use_own = True
                    break
        cont = 0.0
        gp0 = gp1 = 0.0
        vs0 = vs1 = 0.0
        sh0 = sh1 = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if kind[j] == 0:
                continue
            x0, x1, _, rr = pair(pos, i, j, 2)
            if rr >= support or rr == 0.0:
                continue
            if use_own:
                n0, n1 = ni0, ni1
            else:
                n0, n1 = normal[j, 0], normal[j, 1]
            t0, t1 = -n1, n0
            ratio = wall_dist[j] / si
            ub0, ub1 = wall_vel[j, 0], wall_vel[j, 1]
            # divergence velocity (eq. 6)
            ut = ui0 * t0 + ui1 * t1
            un = ((ub0 - ui0) * n0 + (ub1 - ui1) * n1) * ratio + ub0 * n0 + ub1 * n1
            ud0, ud1 = ut * t0 + un * n0, ut * t1 + un * n1
            # Laplacian velocity (eq. 7)
            b = body[j]
            if no_slip[b]:
                lt = ((ub0 - ui0) * t0 + (ub1 - ui1) * t1) * ratio + ub0 * t0 + ub1 * t1
                ln = ui0 * n0 + ui1 * n1
                ul0, ul1 = lt * t0 + ln * n0, lt * t1 + ln * n1
            else:
                ul0, ul1 = ui0, ui1
            # pressure (eq. 8-9) and density from the equation of state
            p_j = p_i + rho_i * ((g0 - accel[j, 0]) * (pos[j, 0] - xi0) + (g1 - accel[j, 1]) * (pos[j, 1] - xi1))
            if eos_b > 0.0:
                base = 1.0 + p_j / eos_b
                rho_j = rho0 * (base if base > 0.0 else 0.0) ** (1.0 / eos_gamma)
            else:
                rho_j = rho0 + p_j / (c0 * c0)
            f = kernel_f(rr, kp)
            vj = vol[j]
            w0, w1 = f * x0 * vj, f * x1 * vj
            cont += (ud0 - ui0) * w0 + (ud1 - ui1) * w1
            pp = p_j + p_i
            pp_i = p_j - p_i if switch else pp
            gp0 += pp_i * w0
            gp1 += pp_i * w1
            pi = -kk * ((ul0 - ui0) * x0 + (ul1 - ui1) * x1) / (rr * rr)
            vs0 += pi * w0
            vs1 += pi * w1
            if with_shift:
                dn = di0 * n0 + di1 * n1
                dt = di0 * t0 + di1 * t1
                dj0, dj1 = dt * t0 - dn * n0, dt * t1 - dn * n1
                ddj = dj0 * w0 + dj1 * w1
                ddi = di0 * w0 + di1 * w1
                cont += (dj0 - di0) * w0 + (dj1 - di1) * w1 - (rho_j * ddj + rho_i * ddi) / rho_i
                if variant == 0:
                    sh0 += rho_j * ud0 * ddj + rho_i * ui0 * ddi
                    sh1 += rho_j * ud1 * ddj + rho_i * ui1 * ddi
            # force of the fluid particle on the body: minus the wall's force on the particle
            fp0, fp1 = v_i * pp * w0, v_i * pp * w1
            fv0, fv1 = -v_i * mu * pi * w0, -v_i * mu * pi * w1
            force[b, 0, 0] += fp0
            force[b, 0, 1] += fp1
            force[b, 1, 0] += fv0
            force[b, 1, 1] += fv1
            cx, cy = xi0 - centers[b, 0], xi1 - centers[b, 1]
            torque[b, 0] += cx * fp1 - cy * fp0
            torque[b, 1] += cx * fv1 - cy * fv0
        d_rho[i] += -rho_i * cont
        if variant == 0:
            d_mom[i, 0] += v_i * (-gp0 + mu * vs0 + sh0)
            d_mom[i, 1] += v_i * (-gp1 + mu * vs1 + sh1)
        else:
            d_mom[i, 0] += (-gp0 + mu * vs0) / rho_i
            d_mom[i, 1] += (-gp1 + mu * vs1) / rho_i
