"""The fluid-solid part of the delta-ALE-SPH right-hand side (numba): clone particles (seed 004 section III)
and, at the end of this module, the fixed-ghost baseline (seed 001 section 6.2).

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
shifting terms), the pressure and the viscous forces (Laplacian velocity) and the momentum's shifting
term (div(rho u du) for delta_ale, div(u du) - u_i div(du) for the other variants, as the fluid pairs);
the diffusive terms D^rho and D^m act between fluid particles only. Their part of <div(rho du)> enters the
density equation and not delta_ale's mass equation (seed 001 eq. 13 has it in both): a clone has no mass
to give or take, so there it would change the fluid's total mass, which eq. 13 conserves. V = m / rho then
changes beside a wall by -(V_i / rho_i) <div(rho du)>_wall more than eq. 9's V div(u + du) (docs/results.md,
"Walls", the cavity's volume budget: without that part in the density equation as well, its volume drifts
less). The force of the walls on each fluid particle is accumulated per body (pressure and viscous parts) for
the body forces; the torque about the body centre too.

The Riemann SPH-ALE scheme (psph.schemes.riemann_ale) takes the same mirrored neighbours, with the wall
treatment the thesis names for it (section 5.5: a partial Riemann problem at the fluid-solid interfaces,
Marongiu 2007): the pair's pressure is p^E of the Riemann problem between i and its mirrored neighbour
(_riemann_pair_pressure), the volume changes by the divergence of the transport velocity, and no mass
crosses a wall (the variants RIEMANN_WALLS and RIEMANN_WALLS_LOW of the kernels below).
"""

import numpy as np
from numba import njit

from psph.compute import eos
from psph.compute.riemann import acoustic_riemann, low_dissipation_pressure
from psph.compute.shift_velocity import fast_power
from psph.compute.smoothing import kernel_f, kernel_w
from psph.compute.sums import pair, solid

# the wall kernels' `variant` for the Riemann SPH-ALE scheme (0-2: delta-ALE's, schemes.delta_ale.VARIANTS):
# its acoustic solver, and with physics.riemann_dissipation = "low" Zhang et al.'s pressure
RIEMANN_WALLS, RIEMANN_WALLS_LOW = 3, 4


@njit(cache=True)
def _riemann_pair_pressure(x0, x1, r, rho_i, p_i, ui0, ui1, rho_j, p_j, ud0, ud1, c0, rho0, tait, variant,
                           pull_free):
    """2 p^E, the Riemann scheme's pair pressure against a mirrored neighbour j (x = x_i - x_j, r = |x|):
    the Riemann problem of psph.compute.riemann between i's own state (first order) and j's (eq. 8-9's
    density, eq. 6's divergence velocity) along e = (x_j - x_i) / r. On a flat wall, with j i's mirror image
    (s_j = s_i) and no body force, u_R = 2 u_b . n - u_L and p_R = p_L, and the acoustic
    p^E = p_i + z (u_i - u_b) . n is the partial Riemann problem at a wall of Marongiu (2007), which the
    thesis names (section 5.5): the wall moves at u_b and pushes back by the impedance z
    (tests/boundaries/test_ghost.py). pull_free (the free-surface region without
    physics.wall_adhesion): p^E >= 0, a wall that never pulls (p^E is the pressure on the wall itself; a
    floor of (p_i + p_j) / 2, delta-ALE's pair, left a drop released under the roof in tension against it,
    falling at 0.76 g)."""
    e0, e1 = -x0 / r, -x1 / r
    u_l, u_r = ui0 * e0 + ui1 * e1, ud0 * e0 + ud1 * e1
    if variant == RIEMANN_WALLS_LOW:
        p_s = low_dissipation_pressure(rho_i, u_l, rho_j, u_r, c0, rho0, tait)
    else:
        p_s = acoustic_riemann(rho_i, u_l, rho_j, u_r, c0, rho0, tait)[2]
    if pull_free:
        p_s = max(p_s, 0.0)
    return 2.0 * p_s


@njit(cache=True)
def _wall_pair(x0, x1, rr, fv, rho_i, p_i, ui0, ui1, di0, di1, rho_j, p_j, ud0, ud1, ul0, ul1, dj0, dj1,
               with_shift, switch, variant, morris, c0, rho0, tait, pull_free):
    """One mirrored neighbour j of fluid particle i (2-D): x = x_i - x_j, rr = |x|, fv = F(r) V_j; j's
    divergence velocity ud, Laplacian velocity ul, shifting velocity dj, pressure and density. Returns the
    continuity sum's term, the pressure term (tensile switch applied), the viscous term (pi_ij, or Morris'
    with morris, as psph.compute.fluid), the du-term of the momentum and the plus-form pressure term (for
    the force on the wall).
    The Riemann scheme's variants (RIEMANN_WALLS, _LOW): the pressure term is 2 p^E
    (_riemann_pair_pressure) in place of p_i + p_j; the continuity term is the divergence of the transport
    velocity v0 = u + du, (v0_j - v0_i) . grad_i W_ij V_j (thesis eq. 5.48's volume flux); no mass crosses
    a wall, so the mass and the convective momentum fluxes (and the du-terms) are zero."""
    w0, w1 = fv * x0, fv * x1
    cont = (ud0 - ui0) * w0 + (ud1 - ui1) * w1
    if variant >= RIEMANN_WALLS:
        pp = _riemann_pair_pressure(x0, x1, rr, rho_i, p_i, ui0, ui1, rho_j, p_j, ud0, ud1, c0, rho0, tait,
                                    variant, pull_free)
        pq = pp
    else:
        pp = p_j + p_i
        pq = p_j - p_i if switch else pp
    if morris:
        v0, v1 = -2.0 * fv * (ul0 - ui0), -2.0 * fv * (ul1 - ui1)
    else:
        pi = -8.0 * ((ul0 - ui0) * x0 + (ul1 - ui1) * x1) / (rr * rr)  # K = 2 (d + 2), d = 2
        v0, v1 = pi * w0, pi * w1
    h0 = h1 = 0.0
    if with_shift and variant >= RIEMANN_WALLS:
        cont += (dj0 - di0) * w0 + (dj1 - di1) * w1
    elif with_shift:
        ddj = dj0 * w0 + dj1 * w1
        ddi = di0 * w0 + di1 * w1
        cont += (dj0 - di0) * w0 + (dj1 - di1) * w1 - (rho_j * ddj + rho_i * ddi) / rho_i
        if variant == 0:  # div(rho u x du)
            h0 = rho_j * ud0 * ddj + rho_i * ui0 * ddi
            h1 = rho_j * ud1 * ddj + rho_i * ui1 * ddi
        else:  # div(u x du) - u_i div(du), as the fluid pairs (psph.compute.fluid)
            div_du = (dj0 - di0) * w0 + (dj1 - di1) * w1
            h0 = ud0 * ddj + ui0 * ddi - ui0 * div_du
            h1 = ud1 * ddj + ui1 * ddi - ui1 * div_du
    return cont, pq * w0, pq * w1, v0, v1, h0, h1, pp * w0, pp * w1


@njit(cache=True)
def _add_rates(i, rho_i, v_i, mu, variant, cont, gp0, gp1, vs0, vs1, sh0, sh1, d_rho, d_mom):
    """Add a row's wall sums to its rates: d_rho and d(m u)/dt (variant 0) or du/dt (1, 2); the Riemann
    scheme's (RIEMANN_WALLS, _LOW): d_rho is dV/dt (V_i times the continuity sum) and d_mom d(m u)/dt."""
    if variant >= RIEMANN_WALLS:
        d_rho[i] += v_i * cont
        d_mom[i, 0] += v_i * (-gp0 + mu * vs0)
        d_mom[i, 1] += v_i * (-gp1 + mu * vs1)
        return
    d_rho[i] += -rho_i * cont
    if variant == 0:
        d_mom[i, 0] += v_i * (-gp0 + mu * vs0 + sh0)
        d_mom[i, 1] += v_i * (-gp1 + mu * vs1 + sh1)
    else:
        d_mom[i, 0] += (-gp0 + mu * vs0) / rho_i + sh0
        d_mom[i, 1] += (-gp1 + mu * vs1) / rho_i + sh1


@njit(cache=True)
def off_walls(near, rows, du):
    """du[rows[r]] (2-D) replaced by the vector closest to it with no positive part along any of near[r]
    (unit normals; zero rows are padding): itself, its projection on one wall's line, or zero (the
    admissible set is a wedge, so its closest point is one of these). boundaries.clone.keep_shift_off."""
    for r in range(rows.size):
        i = rows[r]
        u0, u1 = du[i, 0], du[i, 1]
        tol = 1e-12 * np.sqrt(u0 * u0 + u1 * u1)
        into = False
        for k in range(near.shape[1]):
            if near[r, k, 0] * u0 + near[r, k, 1] * u1 > tol:
                into = True
        if not into:
            continue
        best0 = best1 = 0.0
        miss = np.inf
        for k in range(near.shape[1]):
            n0, n1 = near[r, k, 0], near[r, k, 1]
            along = n0 * u0 + n1 * u1
            if along <= tol or along >= miss:
                continue
            c0, c1 = u0 - along * n0, u1 - along * n1
            ok = True
            for m in range(near.shape[1]):
                if near[r, m, 0] * c0 + near[r, m, 1] * c1 > tol:
                    ok = False
            if ok:
                best0, best1, miss = c0, c1, along
        du[i, 0], du[i, 1] = best0, best1


@njit(cache=True)
def contour_distance(nodes, ends, closest, points):
    """Distance of each of `points` (m, 2) to the contour through the body `nodes` (n, 2), over the two segments
    [a, b] that meet at the point's closest node a = closest[r] (b = ends[a, 0] and ends[a, 1], its neighbours
    along the contour, boundaries.geometry.Profile.ends): min(|x - a|, |x - a - s ab|) with
    s = clip((x - a) . ab / |ab|^2, 0, 1), ab = b - a (s = 0 for a zero-length segment, an open line's end).
    The arithmetic, term by term, of the numpy version it replaces (boundaries.geometry.contour_distance
    calls it), which made about 12 temporaries at every right-hand side (a speed audit): the same bits. An
    index out of range (a k-d tree's "not found", tree.n) raises IndexError, as numpy's indexing did."""
    out = np.empty(points.shape[0])
    for r in range(points.shape[0]):
        a = closest[r]
        if a < 0 or a >= nodes.shape[0]:
            raise IndexError("contour_distance: a closest node index out of range")
        rel0, rel1 = points[r, 0] - nodes[a, 0], points[r, 1] - nodes[a, 1]
        best = np.sqrt(rel0 * rel0 + rel1 * rel1)
        for side in range(2):
            b = ends[a, side]
            ab0, ab1 = nodes[b, 0] - nodes[a, 0], nodes[b, 1] - nodes[a, 1]
            length2 = ab0 * ab0 + ab1 * ab1
            along = (rel0 * ab0 + rel1 * ab1) / (length2 if length2 > 0.0 else 1.0)
            along = np.minimum(np.maximum(along, 0.0), 1.0)  # (np.clip's, NaN kept)
            gap0, gap1 = rel0 - along * ab0, rel1 - along * ab1
            best = np.minimum(best, np.sqrt(gap0 * gap0 + gap1 * gap1))
        out[r] = best
    return out


@njit(cache=True)
def near_wall_rows(kind, ptr, idx):
    """Owned fluid rows (kind 0) with at least one solid neighbour (a wall's or a body's)."""
    out = np.zeros(ptr.size - 1, dtype=np.bool_)
    for i in range(ptr.size - 1):
        if kind[i] != 0:
            continue
        for k in range(ptr[i], ptr[i + 1]):
            if solid(kind[idx[k]]):
                out[i] = True
                break
    return np.flatnonzero(out)


@njit(cache=True)
def clone_viscous_weight(pos, vol, kind, body, normal, wall_dist, rows, s_i_all, no_slip, ptr, idx, kp, ds_min,
                         directional, out):
    """The no-slip clone pairs' weight in the viscous operators beyond an ordinary neighbour's, for their
    stability limit (psph.schemes.viscous_limit, whose sums.largest_kernel_factor_sum counts every pair as a
    fluid one: F_ij V_j, or F_ij V_j e e^T with `directional`, pi_ij's weighting). Seed 004 eq. 7 mirrors the
    tangential velocity as u_j.t = -u_i.t s_j / max(s_i, ds) (a wall at rest, normal part alike), so that
    u_i - u_j = (1 + rho) (u_i.t) t, rho = s_j / max(s_i, ds): with s_i = dx / 2 and s_j up to the support,
    rho reaches 8. Morris' operator weighs u_i - u_j by F V: the pair's block is (1 + rho) F V t t^T, whose
    trace exceeds an ordinary pair's by rho F V, added as rho F V t t^T. pi_ij weighs it by F V e e^T: the
    block is (1 + rho) (e.t) F V e t^T, not symmetric, whose eigenvalues' real parts its symmetric part
    bounds (the numerical range): (1 + rho) (e.t) F V sym(e t^T) - F V e e^T is added (a review: rho F V t t^T,
    added to the pair's e e^T, overweighted a Monaghan Poiseuille flow's wall rows 1.84 / 1.20 times). t is
    the tangent of j's own wall, where clone_rhs takes the row's own normal behind a wall (eq. 5): an
    estimate, as the limit's scaling is. Adds to out[r] (2 x 2) for row rows[r] (s_i_all: nearest_node_data's
    distances, (rows, bodies)). Free-slip pairs (u_j = u_i, weight 0) add nothing: the ordinary pair's count
    stands, a bound."""
    support = 2.0 * kp[1]
    for r in range(rows.size):
        i = rows[r]
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if not solid(kind[j]) or not no_slip[body[j]]:
                continue
            x0, x1, _, rr = pair(pos, i, j, 2)
            if rr >= support or rr == 0.0:
                continue
            fv = -kernel_f(rr, kp) * vol[j]
            ratio = wall_dist[j] / max(s_i_all[r, body[j]], ds_min)
            t0, t1 = -normal[j, 1], normal[j, 0]
            if not directional:
                out[r, 0, 0] += ratio * fv * t0 * t0
                out[r, 0, 1] += ratio * fv * t0 * t1
                out[r, 1, 0] += ratio * fv * t1 * t0
                out[r, 1, 1] += ratio * fv * t1 * t1
                continue
            e0, e1 = x0 / rr, x1 / rr
            c = (1.0 + ratio) * (e0 * t0 + e1 * t1) * fv
            out[r, 0, 0] += c * e0 * t0 - fv * e0 * e0
            out[r, 0, 1] += 0.5 * c * (e0 * t1 + e1 * t0) - fv * e0 * e1
            out[r, 1, 0] += 0.5 * c * (e1 * t0 + e0 * t1) - fv * e1 * e0
            out[r, 1, 1] += c * e1 * t1 - fv * e1 * e1


@njit(cache=True)
def clone_rhs(pos, vol, rho, vel, du, prs, kind, body, normal, wall_dist, accel, wall_vel, rows, n_i_all, s_i_all,
              no_slip, ptr, idx, kp, c0, rho0, tait, mu, morris, gravity, ds_min, variant,
              with_shift, tensile_switch, no_pull, centers, d_rho, d_mom, force, torque, particle_force):
    """Add the solid neighbours' contributions to the owned fluid `rows` (2-D).

    n_i_all, s_i_all: per entry of rows and per body (rows, bodies, 2) and (rows, bodies), the normal of the
    row's closest node on that body and the distance to it; a solid neighbour j is mirrored with those of its
    own body, body[j], and so is eq. 5's test (is the row behind one of that body's solid particles' walls?)
    made per body; wall_vel: the velocity
    of each solid particle's own closest node (u_b of eq. 6-7; the same as the fluid particle's closest
    node's on a smooth rigid wall, and the consistent choice at the corners of a lid).
    no_slip: per body; tait: Tait's equation of state, else the linear (psph.compute.eos).
    variant: the scheme's (_add_rates; RIEMANN_WALLS, _LOW: d_rho receives dV/dt).
    tensile_switch: per particle, 1 where p_j - p_i replaces p_j + p_i in its pressure force when p_i < 0
    (eq. 3; 0 in the free-surface region and where the switch is off).
    no_pull: per particle, 1 where the wall may not pull the particle (the free-surface region without
    physics.wall_adhesion): where eq. 8-9 carried to i's closest wall node x_i + s_i n_i (n_i points into
    the solid), p_i + s_i rho_i (g - a_j) . n_i, is negative, the fluid would need the wall to pull it to
    stay in contact, and the solid neighbour's pressure is taken as max(p_j, 0). A resting contact keeps
    eq. 8-9 (the wall's pressure is positive there). i's own p_i still enters the pair (p_i + p_j), as in
    the fluid's pairs: a particle in tension is still drawn to its neighbours, solid ones included.
    force: (n_bodies, 2, 2) pressure and viscous force of the fluid on each body; torque: (n_bodies, 2), about
    centers, each pair's force applied at the solid particle's wall node x_j - s_j n_j; particle_force: (n_owned,
    2), each fluid row's pressure force on the solids (zero for the other rows), for the wall's load along it.
    """
    support = 2.0 * kp[1]
    g0, g1 = gravity[0], gravity[1]
    use_own = np.zeros(no_slip.size, dtype=np.bool_)
    for r in range(rows.size):
        i = rows[r]
        xi0, xi1 = pos[i, 0], pos[i, 1]
        ui0, ui1 = vel[i, 0], vel[i, 1]
        rho_i, p_i, v_i = rho[i], prs[i], vol[i]
        switch = tensile_switch[i] != 0 and p_i < 0.0
        pull_free = no_pull[i] != 0
        di0 = du[i, 0] if with_shift else 0.0
        di1 = du[i, 1] if with_shift else 0.0
        # eq. 5 (sign corrected): is the particle behind some solid particle's wall, per body?
        use_own[:] = False
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if solid(kind[j]) and normal[j, 0] * (xi0 - pos[j, 0]) + normal[j, 1] * (xi1 - pos[j, 1]) > 0.0:
                x0, x1, _, rr = pair(pos, i, j, 2)
                if rr < support:
                    use_own[body[j]] = True
        cont = 0.0
        gp0 = gp1 = 0.0
        vs0 = vs1 = 0.0
        sh0 = sh1 = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if not solid(kind[j]):
                continue
            x0, x1, _, rr = pair(pos, i, j, 2)
            if rr >= support or rr == 0.0:
                continue
            b = body[j]
            ni0, ni1 = n_i_all[r, b, 0], n_i_all[r, b, 1]
            si = max(s_i_all[r, b], ds_min)
            if use_own[b]:
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
            if no_slip[b]:
                lt = ((ub0 - ui0) * t0 + (ub1 - ui1) * t1) * ratio + ub0 * t0 + ub1 * t1
                ln = ui0 * n0 + ui1 * n1
                ul0, ul1 = lt * t0 + ln * n0, lt * t1 + ln * n1
            else:
                ul0, ul1 = ui0, ui1
            # pressure (eq. 8-9)
            b0, b1 = g0 - accel[j, 0], g1 - accel[j, 1]  # eq. 9's f_j - a_j
            p_j = p_i + rho_i * (b0 * (pos[j, 0] - xi0) + b1 * (pos[j, 1] - xi1))
            # eq. 8-9 carried to i's closest wall node x_i + s_i n_i (the normals point into the solid)
            if pull_free and p_j < 0.0 and p_i + si * rho_i * (b0 * ni0 + b1 * ni1) < 0.0:
                p_j = 0.0  # the wall would pull: no contact pressure below zero
            # shifting velocity: du . n = 0 on the wall
            dn = di0 * n0 + di1 * n1
            dt = di0 * t0 + di1 * t1
            c, q0, q1, v0, v1, h0, h1, f0, f1 = _wall_pair(
                x0, x1, rr, kernel_f(rr, kp) * vol[j], rho_i, p_i, ui0, ui1, di0, di1,
                eos.density(p_j, c0, rho0, tait), p_j, ud0, ud1, ul0, ul1,
                dt * t0 - dn * n0, dt * t1 - dn * n1, with_shift, switch, variant, morris, c0, rho0, tait,
                pull_free)
            cont += c
            gp0 += q0
            gp1 += q1
            vs0 += v0
            vs1 += v1
            sh0 += h0
            sh1 += h1
            # force of the fluid particle on the body: minus the wall's force on the particle
            fp0, fp1 = v_i * f0, v_i * f1
            fv0, fv1 = -v_i * mu * v0, -v_i * mu * v1
            force[b, 0, 0] += fp0
            force[b, 0, 1] += fp1
            particle_force[i, 0] += fp0
            particle_force[i, 1] += fp1
            force[b, 1, 0] += fv0
            force[b, 1, 1] += fv1
            # applied at the solid particle's own wall node x_j - s_j n_j (on body b, whichever body the
            # fluid particle's closest node is on)
            cx = pos[j, 0] - wall_dist[j] * normal[j, 0] - centers[b, 0]
            cy = pos[j, 1] - wall_dist[j] * normal[j, 1] - centers[b, 1]
            torque[b, 0] += cx * fp1 - cy * fp0
            torque[b, 1] += cx * fv1 - cy * fv0
        _add_rates(i, rho_i, v_i, mu, variant, cont, gp0, gp1, vs0, vs1, sh0, sh1, d_rho, d_mom)


# ------------------------------------------------------------------------------------------------------------
# Fixed ghost particles (the baseline; seed 001 section 6.2, Colagrossi & Landrini 2003): the fluid particles
# within a support of an axis-aligned straight wall are mirrored across it, and those near a corner across both
# walls; the image g of fluid particle j carries V_j, p_j + rho_j g . (x_g - x_j), and velocities mirrored
# about the wall velocity u_b: for the divergence the normal part reversed (u_g.n = 2 u_b.n - u_j.n, u_g.t =
# u_j.t), for the Laplacian the whole velocity (u_g = 2 u_b - u_j, no slip; as the divergence, free slip),
# and the shifting velocity with its normal part reversed (du . n = 0 on the wall). A corner image applies
# the two walls' mirrorings in turn. Walls: axis, coordinate c, inward sign (+1: fluid at x_axis > c) and
# velocity u_b. Each image interacts through _wall_pair, as a clone does.


@njit(cache=True)
def _ghost_images(pos, kind, rows, w_axis, w_coord, w_sign, ptr, idx, support, fill, out_ptr, out_j, out_w):
    """Enumerate the (row, j, walls) images: j a fluid neighbour of row i or i itself, mirrored across one
    wall (out_w = [w, -1]) or a corner's two walls of different axes, when the image lies within the
    support of i. fill=False counts them into out_ptr (cumulative per row); fill=True writes them."""
    nw = w_axis.size
    n = 0
    for r in range(rows.size):
        i = rows[r]
        for k in range(ptr[i] - 1, ptr[i + 1]):
            j = i if k < ptr[i] else idx[k]
            if (k >= ptr[i] and j == i) or solid(kind[j]):
                continue
            for w1 in range(nw):
                s1 = w_sign[w1] * (pos[j, w_axis[w1]] - w_coord[w1])
                if s1 >= support:
                    continue
                for w2 in range(w1, nw):
                    a2 = w_axis[w2]
                    if w2 > w1:
                        if a2 == w_axis[w1] or w_sign[w2] * (pos[j, a2] - w_coord[w2]) >= support:
                            continue
                    x0, x1 = _image_position(pos, j, w1, w2 if w2 > w1 else -1, w_axis, w_coord)
                    if (pos[i, 0] - x0) ** 2 + (pos[i, 1] - x1) ** 2 >= support * support:
                        continue
                    if fill:
                        out_j[n] = j
                        out_w[n, 0] = w1
                        out_w[n, 1] = w2 if w2 > w1 else -1
                    n += 1
        if not fill:
            out_ptr[r + 1] = n


def ghost_images(pos, kind, rows, walls, ptr, idx, support):
    """(ptr over rows, j, walls) of the images every row in `rows` sees (see _ghost_images)."""
    axis, coord, sign = walls["axis"], walls["coord"], walls["sign"]
    out_ptr = np.zeros(rows.size + 1, dtype=np.int64)
    dummy_j, dummy_w = np.zeros(0, dtype=np.int64), np.zeros((0, 2), dtype=np.int64)
    _ghost_images(pos, kind, rows, axis, coord, sign, ptr, idx, support, False, out_ptr, dummy_j, dummy_w)
    out_j = np.zeros(out_ptr[-1], dtype=np.int64)
    out_w = np.zeros((out_ptr[-1], 2), dtype=np.int64)
    _ghost_images(pos, kind, rows, axis, coord, sign, ptr, idx, support, True, out_ptr, out_j, out_w)
    return out_ptr, out_j, out_w


@njit(cache=True)
def _image_position(pos, j, w1, w2, w_axis, w_coord):
    """Position of fluid particle j mirrored across wall w1 (and w2 if >= 0)."""
    x0, x1 = pos[j, 0], pos[j, 1]
    for w in (w1, w2):
        if w < 0:
            break
        if w_axis[w] == 0:
            x0 = 2.0 * w_coord[w] - x0
        else:
            x1 = 2.0 * w_coord[w] - x1
    return x0, x1


@njit(cache=True)
def _mirror(vel, du, j, walls, w_axis, w_vel, no_slip):
    """Velocities of the image of fluid particle j across walls[0] (and walls[1] if >= 0): divergence,
    Laplacian and shifting velocity. A corner image is mirrored across the x-wall (walls[0], the lower
    index) first, so a no-slip corner image below a moving lid gets 2 u_lid - (2 u_side - u) = u + 2 u_lid:
    the lid's velocity is discontinuous at its corners, and this choice lets the lid drag its corners'
    fluid as it drags the rest of the top layer."""
    ud = np.array([vel[j, 0], vel[j, 1]])
    ul = ud.copy()
    dd = np.array([du[j, 0], du[j, 1]])
    for m in range(2):
        w = walls[m]
        if w < 0:
            break
        a = w_axis[w]
        ud[a] = 2.0 * w_vel[w, a] - ud[a]
        if no_slip:
            ul[0] = 2.0 * w_vel[w, 0] - ul[0]
            ul[1] = 2.0 * w_vel[w, 1] - ul[1]
        else:
            ul[a] = 2.0 * w_vel[w, a] - ul[a]
        dd[a] = -dd[a]
    return ud, ul, dd


@njit(cache=True)
def ghost_rhs(pos, vol, rho, vel, du, prs, rows, img_ptr, img_j, img_w, w_axis, w_coord, w_vel, no_slip, kp, c0,
              rho0, tait, mu, morris, gravity, variant, with_shift, tensile_switch, d_rho, d_mom):
    """Add the ghost images' contributions to the owned fluid `rows` (2-D; images from ghost_images)."""
    for r in range(rows.size):
        i = rows[r]
        rho_i, p_i, v_i = rho[i], prs[i], vol[i]
        ui0, ui1 = vel[i, 0], vel[i, 1]
        di0 = du[i, 0] if with_shift else 0.0
        di1 = du[i, 1] if with_shift else 0.0
        switch = tensile_switch[i] != 0 and p_i < 0.0
        cont = gp0 = gp1 = vs0 = vs1 = sh0 = sh1 = 0.0
        for k in range(img_ptr[r], img_ptr[r + 1]):
            j = img_j[k]
            g0, g1 = _image_position(pos, j, img_w[k, 0], img_w[k, 1], w_axis, w_coord)
            ud, ul, dd = _mirror(vel, du, j, img_w[k], w_axis, w_vel, no_slip)
            x0, x1 = pos[i, 0] - g0, pos[i, 1] - g1
            rr = np.sqrt(x0 * x0 + x1 * x1)
            if rr == 0.0:  # a particle on the wall meets its own image: no direction, no force
                continue
            p_g = prs[j] + rho[j] * (gravity[0] * (g0 - pos[j, 0]) + gravity[1] * (g1 - pos[j, 1]))
            c, q0, q1, v0, v1, h0, h1, _, _ = _wall_pair(
                x0, x1, rr, kernel_f(rr, kp) * vol[j], rho_i, p_i, ui0, ui1, di0, di1,
                eos.density(p_g, c0, rho0, tait), p_g, ud[0], ud[1], ul[0], ul[1],
                dd[0] if with_shift else 0.0, dd[1] if with_shift else 0.0, with_shift, switch, variant, morris,
                c0, rho0, tait, False)
            cont += c
            gp0 += q0
            gp1 += q1
            vs0 += v0
            vs1 += v1
            sh0 += h0
            sh1 += h1
        _add_rates(i, rho_i, v_i, mu, variant, cont, gp0, gp1, vs0, vs1, sh0, sh1, d_rho, d_mom)


# ghost_grad_c's `mat` when only grad C is wanted
NO_MATRIX = np.zeros((0, 2, 2))


@njit(cache=True)
def ghost_grad_c(pos, vol, rows, img_ptr, img_j, img_w, w_axis, w_coord, kp, coeff, power, w_ref, out, mat):
    """Add the images' part of grad C^ = sum_g F(r_ig) V_g [1 + coeff (W_ig / w_ref)^power] x_ig to out, and
    unless mat is empty (NO_MATRIX) their part of the renormalisation matrix, mat -= F V_g x_ig x_ig^T
    (compute.sums.renormalisation_and_grad_c, with coeff = 0: the free-surface detection's sums)."""
    with_mat = mat.shape[0] > 0
    for r in range(rows.size):
        i = rows[r]
        for k in range(img_ptr[r], img_ptr[r + 1]):
            g0, g1 = _image_position(pos, img_j[k], img_w[k, 0], img_w[k, 1], w_axis, w_coord)
            x0, x1 = pos[i, 0] - g0, pos[i, 1] - g1
            rr = np.sqrt(x0 * x0 + x1 * x1)
            if rr == 0.0:
                continue
            s = kernel_f(rr, kp) * vol[img_j[k]]
            if with_mat:
                mat[i, 0, 0] -= s * x0 * x0
                mat[i, 0, 1] -= s * x0 * x1
                mat[i, 1, 0] -= s * x0 * x1
                mat[i, 1, 1] -= s * x1 * x1
            if coeff != 0.0:
                s *= 1.0 + coeff * fast_power(kernel_w(rr, kp) / w_ref, power)
            out[i, 0] += s * x0
            out[i, 1] += s * x1
