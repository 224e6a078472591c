"""Free-surface detection kernels (numba; no communication): Marrone et al.'s algorithm (J. Comput. Phys.
229 (2010) 3652, reference [25] of seed 004, which detects the free surface with it; the indicator lambda is
thesis 000 eq. 6.28, which prints the inverse of M_i below and means the smallest eigenvalue of M_i, and
prints the volume omega_i where the sum needs omega_j, V_j below).

    M_i      = sum_j (x_j - x_i) (x) grad_i W_ij V_j          (compute.sums.renormalisation_matrix)
    lambda_i = smallest eigenvalue of M_i: about 1 in a full support, about 1/2 on a flat surface, 0 alone
    n_i      = nu_i / |nu_i|,  nu_i = -M_i^{-1} sum_j grad_i W_ij V_j   (outward: the renormalised gradient of
               the colour function 1, sign reversed), at the surface particles; in the region about them, the
               kernel-weighted mean of their normals (region_normals)

A fluid particle is at the surface if lambda_i <= lambda_surface (0.2), never if lambda_i > lambda_interior
(0.75); in between it is when its scan region is empty: no fluid (or inflow) neighbour j with

    |x_ji| >= sqrt(2) h  and  |x_j - T_i| < h,      T_i = x_i + h n_i, or
    |x_ji| <  sqrt(2) h  and  angle(x_ji, n_i) < pi/4,

the umbrella-shaped region of Marrone et al. (a disc, in 3-D a ball, of radius h about T_i, and the
quarter-cone from x_i to it; in 2-D the cone part is their square |n.(x_j - T)| + |t.(x_j - T)| < h, which
within sqrt(2) h of x_i is exactly the cone). Neighbours on the region's edge, to a relative 1e-9, count as
outside. h is psph's smoothing length, half its kernels' support; Marrone et al. scale the region with their
own kernel's h (README, Free surfaces). Solid particles count in M_i (a wall fills the support) but not in
the scan region: fluid facing a wall across an air gap (a jet's front coming down on a plate, a tank's
contact line under the wall's solids above it) is at a surface as long as lambda_i stays in the scan band.
"""

import numpy as np
from numba import njit

from psph.compute.smoothing import kernel_w
from psph.compute.sums import dot, load, pair, pair2, solve_symmetric, store, symmetric

SURFACE = 2  # flag of a particle on the free surface
REGION = 1  # flag of a particle within a kernel support of one (seed 004: "the free-surface particles and
# their neighbouring particles")
# a lattice puts neighbours exactly on the scan region's and the support's edges (at 45 degrees from an axis,
# at distance h from T, at 2h): such ties count as outside, by this relative margin, so that round-off (which
# differs with the rank count) cannot decide them
TIE = 1e-9
# a normal is undefined (zero) where the vector it normalises is below this relative size: round-off then sets
# its direction (the middle row of a three-row sheet has |L grad C| h ~ 5e-15)
UNDEFINED = 1e-6


@njit(cache=True)
def outward_normals(mat, lam, grad_c, h, tol, out):
    """n_i = -L_i grad C_i / |L_i grad C_i|, L_i = M_i^{-1} (the identity where lambda_min(M_i) = lam[i] <= tol,
    as sums.invert_renormalisation); zero where |L_i grad C_i| h <= UNDEFINED (a full or balanced support: at
    a flat surface it is about 0.5)."""
    n, d = grad_c.shape
    for i in range(n):
        g0, g1, g2 = load(grad_c, i, d)
        if lam[i] > tol:
            m00, m01, m02, m11, m12, m22 = symmetric(mat, i, d)  # (no *args: solve_symmetric is inlined)
            g0, g1, g2 = solve_symmetric(m00, m01, m02, m11, m12, m22, g0, g1, g2, d, 0.0)
        norm = np.sqrt(dot(g0, g1, g2, g0, g1, g2, d))
        if norm * h > UNDEFINED:
            store(out, i, d, -g0 / norm, -g1 / norm, -g2 / norm)
        else:
            store(out, i, d, 0.0, 0.0, 0.0)


@njit(cache=True)
def scan_surface(pos, fluid, blocks, lam, normal, ptr, idx, h, lam_surface, lam_interior, flag):
    """flag[i] = SURFACE for the owned fluid particles at the free surface, 0 for the other owned rows.
    blocks: the local particles that fill a scan region (the fluid's, not the solids')."""
    d = pos.shape[1]
    far2 = 2.0 * h * h  # (sqrt(2) h)^2
    for i in range(ptr.size - 1):
        flag[i] = 0
        if not fluid[i] or lam[i] > lam_interior:
            continue
        if lam[i] <= lam_surface:
            flag[i] = SURFACE
            continue
        n0, n1, n2 = load(normal, i, d)
        if dot(n0, n1, n2, n0, n1, n2, d) == 0.0:
            continue  # no direction to scan: not a surface
        empty = True
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if not blocks[j]:
                continue
            r0, r1, r2, rr = pair2(pos, i, j, d)  # x_ij = x_i - x_j
            if rr >= far2:
                t0, t1, t2 = h * n0 + r0, h * n1 + r1, h * n2 + r2  # T_i - x_j
                inside = dot(t0, t1, t2, t0, t1, t2, d) < h * h * (1.0 - TIE)
            else:
                along = -dot(n0, n1, n2, r0, r1, r2, d)  # n . x_ji
                inside = along > 0.0 and 2.0 * along * along > rr * (1.0 + TIE)
            if inside:
                empty = False
                break
        if empty:
            flag[i] = SURFACE


@njit(cache=True)
def mark_region(pos, fluid, ptr, idx, support, flag):
    """flag[i] = REGION for the owned fluid particles not at the surface with a SURFACE neighbour (the halo's
    flags must be current) within the kernel support."""
    d = pos.shape[1]
    reach2 = support * support * (1.0 - TIE)
    for i in range(ptr.size - 1):
        if not fluid[i] or flag[i] == SURFACE:
            continue
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if flag[j] == SURFACE and pair2(pos, i, j, d)[3] < reach2:
                flag[i] = REGION
                break


@njit(cache=True)
def region_normals(pos, flag, ptr, idx, kp, normal):
    """The normals of the free-surface region: at a REGION particle, the kernel-weighted mean of its SURFACE
    neighbours' normals (the halo's must be current), normalised, or zero where it is below UNDEFINED times
    the weights' sum (surfaces on opposite sides balance, as in a sheet's middle row); at interior particles,
    zero. A region particle's own n_i is ill-conditioned (its support is nearly full, so nu_i is small: at
    2.65 dx below a drop's rim its direction moved by 1e-5 between runs on 1 and 2 ranks within 20 steps);
    the surface's normal nearby is not."""
    d = pos.shape[1]
    for i in range(ptr.size - 1):
        if flag[i] == SURFACE:
            continue
        s0, s1, s2, weights = 0.0, 0.0, 0.0, 0.0
        if flag[i] == REGION:
            for k in range(ptr[i], ptr[i + 1]):
                j = idx[k]
                if flag[j] == SURFACE:
                    w = kernel_w(pair(pos, i, j, d)[3], kp)
                    weights += w
                    n0, n1, n2 = load(normal, j, d)
                    s0 += w * n0
                    s1 += w * n1
                    s2 += w * n2
        norm = np.sqrt(dot(s0, s1, s2, s0, s1, s2, d))
        if norm > UNDEFINED * weights:
            s0, s1, s2 = s0 / norm, s1 / norm, s2 / norm
        else:
            s0, s1, s2 = 0.0, 0.0, 0.0
        store(normal, i, d, s0, s1, s2)


@njit(cache=True)
def restrict_shift(flag, lam, normal, lam_normal, du):
    """Thesis eq. 6.29 (Sun et al.'s delta+-SPH): in the free-surface region (flag > 0) du = 0 where
    lambda_i < lam_normal (0.4) or the normal is undefined, else du = (I - n (x) n) du; elsewhere unchanged."""
    n, d = du.shape
    for i in range(n):
        if flag[i] == 0:
            continue
        norm2 = 0.0
        along = 0.0
        for a in range(d):
            norm2 += normal[i, a] * normal[i, a]
            along += normal[i, a] * du[i, a]
        for a in range(d):
            if lam[i] < lam_normal or norm2 == 0.0:
                du[i, a] = 0.0
            else:
                du[i, a] -= along * normal[i, a]
