"""Per-particle SPH sums over CSR neighbour lists (numba; no communication).

Conventions (thesis 000 section 4.1.3, seed 001 section 3):
    x_ij = x_i - x_j,  r = |x_ij|,  grad_i W_ij = f(r) x_ij  with f = W'(r)/r (compute.smoothing),
    V_j  = particle volume (the thesis' omega_j).
Every function fills `out` for the rows 0..n_rows-1 of the list (n_rows = ptr.size - 1, the owned
particles); neighbours j index all local particles (owned + halo), whose fields must be current.
"""

import numpy as np
from numba import njit

from psph.compute.jit import per_dimension
from psph.compute.smoothing import kernel_f, kernel_w


@njit(cache=True, inline="always")
def solid(kind):
    """Is a particle of this kind (psph.particles.Kind) a wall's or a body's? Inflow particles are fluid to
    their neighbours' sums; only solids are mirrored or left out of the fluid's own terms."""
    return kind == 1 or kind == 2


@njit(cache=True, inline="always")
def pair2(pos, i, j, d):
    """(x_ij components padded to 3, r^2); with a compile-time d only the d components are computed."""
    r0 = pos[i, 0] - pos[j, 0]
    r1 = pos[i, 1] - pos[j, 1] if d > 1 else 0.0
    r2 = pos[i, 2] - pos[j, 2] if d > 2 else 0.0
    return r0, r1, r2, dot(r0, r1, r2, r0, r1, r2, d)


@njit(cache=True, inline="always")
def dot(a0, a1, a2, b0, b1, b2, d):
    """a . b over the first d components."""
    s = a0 * b0
    if d > 1:
        s += a1 * b1
    if d > 2:
        s += a2 * b2
    return s


@njit(cache=True, inline="always")
def load(arr, i, d):
    """Row i of an (n, d) array, padded to 3 components."""
    return arr[i, 0], arr[i, 1] if d > 1 else 0.0, arr[i, 2] if d > 2 else 0.0


# inline: no helper taking d is compiled on its own. A kernel of psph.compute.jit.per_dimension passes d as a
# literal, and a helper's specialisations for d = 1, 2, 3 share one cache index, which two processes compiling
# different dimensions at once (the test script's warm-up) could leave pointing d = 1's entry at d = 2's code:
# a CI run failed with "Invalid use of type(CPUDispatcher(store)) with parameters (..., Literal[int](1), ...)
# Known signatures: (..., Literal[int](2), ...)"
@njit(cache=True, inline="always")
def pair(pos, i, j, d):
    """(x_ij components padded to 3, r) for particles i, j."""
    r0, r1, r2, rr = pair2(pos, i, j, d)
    return r0, r1, r2, np.sqrt(rr)


@njit(cache=True, inline="always")
def store(out, i, d, g0, g1, g2):
    out[i, 0] = g0
    if d > 1:
        out[i, 1] = g1
    if d > 2:
        out[i, 2] = g2


@njit(cache=True)
def concentration(pos, vol, ptr, idx, kp, out):
    """C_i = sum_j W_ij V_j including the self term (thesis eq. 4.33, 6.8)."""
    d = pos.shape[1]
    w0 = kernel_w(0.0, kp)
    for i in range(ptr.size - 1):
        c = w0 * vol[i]
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            c += kernel_w(pair(pos, i, j, d)[3], kp) * vol[j]
        out[i] = c


def _grad_concentration_for(d):
    """grad_concentration's kernel for dimension d (compute.jit.per_dimension: 25% faster in 2-D)."""

    @per_dimension(d)
    def kernel(pos, vol, ptr, idx, kp, out):
        for i in range(ptr.size - 1):
            g0 = 0.0
            g1 = 0.0
            g2 = 0.0
            for k in range(ptr[i], ptr[i + 1]):
                j = idx[k]
                r0, r1, r2, r = pair(pos, i, j, d)
                s = kernel_f(r, kp) * vol[j]
                g0 += s * r0
                g1 += s * r1
                g2 += s * r2
            store(out, i, d, g0, g1, g2)

    return kernel


GRAD_CONCENTRATION = {d: _grad_concentration_for(d) for d in (1, 2, 3)}


def grad_concentration(pos, vol, ptr, idx, kp, out):
    """grad C_i = sum_j grad_i W_ij V_j (thesis eq. 4.34, 8.18-8.19 up to the sign convention)."""
    GRAD_CONCENTRATION[pos.shape[1]](pos, vol, ptr, idx, kp, out)


@njit(cache=True)
def gradient(pos, vol, ptr, idx, kp, phi, out):
    """Plain SPH gradient of a scalar: sum_j phi_j grad_i W_ij V_j (thesis eq. 4.31)."""
    d = pos.shape[1]
    for i in range(ptr.size - 1):
        g0 = 0.0
        g1 = 0.0
        g2 = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            r0, r1, r2, r = pair(pos, i, j, d)
            s = kernel_f(r, kp) * vol[j] * phi[j]
            g0 += s * r0
            g1 += s * r1
            g2 += s * r2
        store(out, i, d, g0, g1, g2)


@njit(cache=True)
def gradient_difference(pos, vol, ptr, idx, kp, phi, out):
    """Difference-form gradient of a scalar: sum_j (phi_j - phi_i) grad_i W_ij V_j (seed 001 eq. 15 before its
    renormalisation; exact for a constant phi)."""
    d = pos.shape[1]
    for i in range(ptr.size - 1):
        g0 = 0.0
        g1 = 0.0
        g2 = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            r0, r1, r2, r = pair(pos, i, j, d)
            s = kernel_f(r, kp) * vol[j] * (phi[j] - phi[i])
            g0 += s * r0
            g1 += s * r1
            g2 += s * r2
        store(out, i, d, g0, g1, g2)


@njit(cache=True)
def apply_renormalisation(lmat, grad):
    """grad_i <- L_i grad_i in place (renormalised gradient, seed 001 eq. 15)."""
    n, d = grad.shape
    tmp = np.empty(d)
    for i in range(n):
        for a in range(d):
            s = 0.0
            for b in range(d):
                s += lmat[i, a, b] * grad[i, b]
            tmp[a] = s
        for a in range(d):
            grad[i, a] = tmp[a]


@njit(cache=True)
def divergence(pos, vol, ptr, idx, kp, u, out):
    """Difference-form divergence: sum_j (u_j - u_i) . grad_i W_ij V_j (seed 001 eq. 11)."""
    d = pos.shape[1]
    for i in range(ptr.size - 1):
        s = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            r0, r1, r2, r = pair(pos, i, j, d)
            du = (u[j, 0] - u[i, 0]) * r0
            if d > 1:
                du += (u[j, 1] - u[i, 1]) * r1
            if d > 2:
                du += (u[j, 2] - u[i, 2]) * r2
            s += kernel_f(r, kp) * vol[j] * du
        out[i] = s


@njit(cache=True)
def largest_kernel_factor_sum(pos, vol, ptr, idx, kp, rows, directional, extra):
    """The largest over `rows` of sum_j F_ij V_j (F_ij = -W'(r)/r >= 0, seed 001 eq. 14's factor: the diagonal
    of Morris' Laplacian over 2) or, with `directional`, of the largest eigenvalue of the d x d matrix
    sum_j F_ij V_j e_ij e_ij^T (e_ij = x_ij / r, the pi_ij operator's weighting: particles packed closer along one
    direction widen its spectrum in that direction). Their excess over the lattice's scales the viscous
    operators' largest eigenvalue (psph.schemes.viscous_limit). extra: (len(rows), d, d) added to each row's
    matrix (its trace to the scalar sum): the no-slip clone walls' weight (compute.walls.clone_viscous_weight),
    or an empty array. 0 without rows."""
    d = pos.shape[1]
    largest = 0.0
    a = np.zeros((d, d))
    for m in range(rows.size):
        i = rows[m]
        a[:] = 0.0
        if extra.shape[0]:
            if directional:
                a[:] = extra[m]
            else:
                for p in range(d):
                    a[0, 0] += extra[m, p, p]
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            r0, r1, r2, r = pair(pos, i, j, d)
            w = -kernel_f(r, kp) * vol[j]
            if not directional:
                a[0, 0] += w
                continue
            if r == 0.0:  # no direction: pi_ij leaves the pair out
                continue
            e = (r0 / r, r1 / r, r2 / r)
            for p in range(d):
                for q in range(d):
                    a[p, q] += w * e[p] * e[q]
        if not directional or d == 1:
            top = a[0, 0]
        elif d == 2:
            half = 0.5 * (a[0, 0] + a[1, 1])
            top = half + np.sqrt(0.25 * (a[0, 0] - a[1, 1]) ** 2 + a[0, 1] * a[1, 0])
        else:
            top = np.linalg.eigvalsh(a)[-1]
        largest = max(largest, top)
    return largest


@njit(cache=True)
def laplacian_morris(pos, vol, ptr, idx, kp, phi, out):
    """Morris Laplacian of a scalar: 2 sum_j (phi_j - phi_i) F_ij V_j, F_ij = x_ji.grad_i W_ij / r^2.

    F_ij is the seed 001 eq. 14 kernel factor; with grad_i W_ij = f x_ij it equals -f(r) >= 0.
    """
    for i in range(ptr.size - 1):
        s = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            r = pair(pos, i, j, pos.shape[1])[3]
            s -= kernel_f(r, kp) * vol[j] * (phi[j] - phi[i])
        out[i] = 2.0 * s


@njit(cache=True)
def viscous_pi(pos, vol, ptr, idx, kp, u, out):
    """sum_j pi_ij grad_i W_ij V_j with pi_ij = K (u_j - u_i).x_ji / |x_ji|^2, K = 2 (d + 2).

    Seed 001 eq. 11: mu times this sum approximates div of the viscous stress (mu lap u for a
    divergence-free u). Coincident pairs (r = 0) contribute nothing.
    """
    d = pos.shape[1]
    kk = 2.0 * (d + 2)
    for i in range(ptr.size - 1):
        g0 = 0.0
        g1 = 0.0
        g2 = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            r0, r1, r2, r = pair(pos, i, j, d)
            if r == 0.0:
                continue
            # (u_j - u_i) . x_ji = -(u_j - u_i) . x_ij
            du = (u[j, 0] - u[i, 0]) * r0
            if d > 1:
                du += (u[j, 1] - u[i, 1]) * r1
            if d > 2:
                du += (u[j, 2] - u[i, 2]) * r2
            s = -kk * du / (r * r) * kernel_f(r, kp) * vol[j]
            g0 += s * r0
            g1 += s * r1
            g2 += s * r2
        store(out, i, d, g0, g1, g2)


@njit(cache=True)
def renormalisation_matrix(pos, vol, ptr, idx, kp, out):
    """M_i = sum_j (x_j - x_i) (x) grad_i W_ij V_j (symmetric; = I on a full, regular support).

    The renormalisation matrix of seed 001 eq. 15 (index misprint corrected, seeds/README.md) is
    L_i = M_i^{-1}: see invert_renormalisation.
    """
    renormalisation_and_grad_c(pos, vol, ptr, idx, kp, out, np.empty((ptr.size - 1, pos.shape[1])))


@njit(cache=True)
def renormalisation_and_grad_c(pos, vol, ptr, idx, kp, mat, grad):
    """M_i into mat (renormalisation_matrix) and grad C_i into grad (grad_concentration), in one pass."""
    d = pos.shape[1]
    for i in range(ptr.size - 1):
        m00 = m01 = m02 = m11 = m12 = m22 = 0.0
        g0 = g1 = g2 = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            r0, r1, r2, r = pair(pos, i, j, d)
            s = kernel_f(r, kp) * vol[j]
            g0 += s * r0
            m00 -= s * r0 * r0
            if d > 1:
                g1 += s * r1
                m01 -= s * r0 * r1
                m11 -= s * r1 * r1
            if d > 2:
                g2 += s * r2
                m02 -= s * r0 * r2
                m12 -= s * r1 * r2
                m22 -= s * r2 * r2
        store(grad, i, d, g0, g1, g2)
        mat[i, 0, 0] = m00
        if d > 1:
            mat[i, 0, 1] = mat[i, 1, 0] = m01
            mat[i, 1, 1] = m11
        if d > 2:
            mat[i, 0, 2] = mat[i, 2, 0] = m02
            mat[i, 1, 2] = mat[i, 2, 1] = m12
            mat[i, 2, 2] = m22


@njit(cache=True, inline="always")
def symmetric(mat, i, d):
    """The upper triangle (m00, m01, m02, m11, m12, m22) of mat[i], padded with zeros beyond d."""
    m01 = mat[i, 0, 1] if d > 1 else 0.0
    m11 = mat[i, 1, 1] if d > 1 else 0.0
    m02 = mat[i, 0, 2] if d > 2 else 0.0
    m12 = mat[i, 1, 2] if d > 2 else 0.0
    m22 = mat[i, 2, 2] if d > 2 else 0.0
    return mat[i, 0, 0], m01, m02, m11, m12, m22


@njit(cache=True)
def smallest_eigenvalue(mat, out):
    """Smallest eigenvalue of each symmetric d x d matrix (lambda_min of M_i, free-surface indicator): in
    closed form for d <= 2; in 3-D by LAPACK (the trigonometric closed form loses half the digits where two
    eigenvalues meet, as at a flat surface's M = diag(1, 1, 1/2))."""
    d = mat.shape[1]
    for i in range(mat.shape[0]):
        if d == 1:
            out[i] = mat[i, 0, 0]
        elif d == 2:
            a, b, c = mat[i, 0, 0], mat[i, 0, 1], mat[i, 1, 1]
            out[i] = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) * (a - c) + b * b)
        else:
            out[i] = np.linalg.eigvalsh(np.ascontiguousarray(mat[i]))[0]


@njit(cache=True, inline="always")
def solve_symmetric(m00, m01, m02, m11, m12, m22, g0, g1, g2, d, tol):
    """x = M^-1 g for a symmetric d x d M by cofactors (g itself where det M <= tol^d: near-singular, no
    renormalisation)."""
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
def invert_renormalisation(mat, lambda_min, tol, out):
    """L_i = M_i^{-1} where lambda_min(M_i) > tol, else the identity (no renormalisation)."""
    d = mat.shape[1]
    for i in range(mat.shape[0]):
        m00, m01, m02, m11, m12, m22 = symmetric(mat, i, d)  # (no *args: solve_symmetric is inlined)
        for b in range(d):
            e0, e1, e2 = (1.0 if b == 0 else 0.0), (1.0 if b == 1 else 0.0), (1.0 if b == 2 else 0.0)
            if lambda_min[i] > tol:  # then det M_i > tol^d > 0
                e0, e1, e2 = solve_symmetric(m00, m01, m02, m11, m12, m22, e0, e1, e2, d, 0.0)
            out[i, 0, b] = e0
            if d > 1:
                out[i, 1, b] = e1
            if d > 2:
                out[i, 2, b] = e2


@njit(cache=True)
def nearest_distance(pos, ptr, idx, row_group, col_group, out):
    """Distance from each particle i to its nearest neighbour j != i with col_group[j] == row_group[i] (inf
    if none): with both the kinds, particles drawing closer than the lattice allows (pairing) show here long
    before grad C sees them; with row_group 0 and col_group 0 at the solids only, the distance to the
    nearest solid particle."""
    d = pos.shape[1]
    for i in range(ptr.size - 1):
        best = np.inf
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if j == i or col_group[j] != row_group[i]:
                continue
            rr = pair2(pos, i, j, d)[3]
            if rr < best:
                best = rr
        out[i] = np.sqrt(best)


@njit(cache=True)
def shepard_from_fluid(pos, vol, kind, rows, ptr, idx, kp, density, velocity, floor, rho_floor):
    """For every row i of `rows` (owned), the Shepard average over its fluid neighbours j (kind 0) of the
    density and the velocity, sum_j f_j W_ij V_j / sum_j W_ij V_j: the zero-gradient extrapolation an
    outflow buffer holds (psph.boundaries.open). A row with no fluid within its support keeps its values.
    Fills density[i] and velocity[i] in place. floor = 0: the plain average.

    floor > 0 (an inflow buffer's density): where the fluid's weight sum_j W_ij V_j is below `floor`, the
    density is (sum_j rho_j W_ij V_j + (floor - sum_j W_ij V_j) rho_floor) / floor, continuous in the
    positions down to rho_floor with no fluid; the plain average jumps to rho_j as a single fluid neighbour
    enters the support with a vanishing weight, which let round-off decide a buffer particle's density
    (1e-4 apart between 1 and 2 ranks in a jet with IIPS + MLS II, a test found)."""
    d = pos.shape[1]
    for i in rows:
        wsum, rho = 0.0, 0.0
        u0, u1, u2 = 0.0, 0.0, 0.0
        for k in range(ptr[i], ptr[i + 1]):
            j = idx[k]
            if kind[j] != 0:
                continue
            r = np.sqrt(pair2(pos, i, j, d)[3])
            w = kernel_w(r, kp) * vol[j]
            wsum += w
            rho += w * density[j]
            v0, v1, v2 = load(velocity, j, d)
            u0 += w * v0
            u1 += w * v1
            u2 += w * v2
        if floor > 0.0 and wsum < floor:
            density[i] = (rho + (floor - wsum) * rho_floor) / floor
        elif wsum > 0.0:
            density[i] = rho / wsum
            store(velocity, i, d, u0 / wsum, u1 / wsum, u2 / wsum)
