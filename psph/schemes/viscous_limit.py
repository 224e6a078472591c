"""The time step the explicit viscous term allows: dt <= SAFETY x beta / (nu lambda_max).

lambda_max is the largest eigenvalue of the discrete viscous operator (per unit nu) and beta how far the
integrator's stability polynomial reaches along the negative real axis (RK3: |1 + z + z^2/2 + z^3/6| <= 1
down to z = -2.5127; RK4 down to -2.7853; tests/schemes/test_viscous_limit.py finds both roots).

The fixed limit 0.125 h^2 / nu (Morris et al. 1997, for their Laplacian and the cubic spline) psph used
before is unstable with the pi_ij operator (seed 001 eq. 11) and Wendland C6 at h/dx = 2: there
lambda_max h^2 = 30.2 on the lattice, so RK3 needs dt nu / h^2 <= 0.083, and a Taylor-Green at Re = 0.01
blew up in its first steps. lambda_max is taken here from the operator's Fourier symbol on the Cartesian
lattice of the scene's spacing (exact for the lattice: it equals the eigenvalues of the assembled operator
on a periodic lattice, which the test checks), scaled by how much the particles' largest diagonal weight
exceeds the lattice's: for Morris' operator sum_j V_j F_ij, for pi_ij the largest eigenvalue of
sum_j V_j F_ij e_ij e_ij^T, whose direction matters (a lattice stretched 2 times along x and squeezed along y
raises pi_ij's lambda_max more than the scalar sum shows). Disorder and stretching widen the spectrum (up to
3.6 times the lattice's in the checks). Against the assembled operator on perturbed (sigma up to 0.8 dx)
and stretched (up to 2 times) periodic lattices, with Wendland C2, C4, C6 and the cubic spline at h/dx =
1.2-2.5 and both operators, the estimate lies within 0.96-1.58 of the true lambda_max (224 cases, 2-D:
run_scripts/viscous_limit_check.py; tests/schemes/test_viscous_limit.py checks a subset and 3-D); SAFETY =
0.8 covers the low side.
"""

import numpy as np

from psph.boundaries.clone import NO_WALLS
from psph.compute.sums import largest_kernel_factor_sum
from psph.diagnostics import fluid_mask
from psph.parallel.comm import allreduce_max

# -z where |R(z)| = 1 on the negative real axis, R the integrator's stability polynomial (its Taylor
# polynomial of exp: every s-stage RK of order s <= 4 has it)
REAL_AXIS_REACH = {"rk3": 2.5127453266183286, "rk4": 2.785293563405282}
SAFETY = 0.8


def lattice_offsets(kernel, dim: int, dx: float) -> tuple:
    """The Cartesian lattice's neighbour offsets within the support, their lengths and weights V F_j."""
    reach = int(np.ceil(kernel.support / dx))
    axis = np.arange(-reach, reach + 1)
    offsets = np.stack(np.meshgrid(*[axis] * dim, indexing="ij"), axis=-1).reshape(-1, dim) * dx
    r = np.linalg.norm(offsets, axis=1)
    keep = (r > 0.0) & (r < kernel.support)
    return offsets[keep], r[keep], -kernel.radial(r[keep]) * dx ** dim  # F = -W'(r)/r >= 0


def zone_maximum(largest, dim: int, top: float) -> float:
    """The maximum over k in [0, top]^d of largest(k) (k: an (m, d) array of waves -> m values): over a grid
    of 33 points per axis (17 in 3-D), then refined from the grid's best point by bounded L-BFGS-B (a 3-D
    audit: the 17-point grid alone put Wendland C6's explicit-shifting limit at 0.4630 h^2, where 33 points
    give 0.4615)."""
    from scipy.optimize import minimize

    waves = np.linspace(0.0, top, 33 if dim < 3 else 17)
    k = np.stack(np.meshgrid(*[waves] * dim, indexing="ij"), axis=-1).reshape(-1, dim)
    values = largest(k)
    best = k[int(np.argmax(values))]
    refined = minimize(lambda q: -float(largest(q[None, :])[0]), best, method="L-BFGS-B", bounds=[(0.0, top)] * dim)
    return max(float(values.max()), -float(refined.fun))


def lattice_symbol(kernel, dim: int, dx: float, morris: bool) -> tuple:
    """(lambda_max, D): the largest eigenvalue, per unit nu, of the viscous operator on the Cartesian lattice
    of spacing dx, from its Fourier symbol over the Brillouin zone, and the lattice's diagonal weight D (what
    sums.largest_kernel_factor_sum gives there): Morris' sum_j V F_j; pi_ij's largest eigenvalue of
    sum_j V F_j e_j e_j^T (F = -W'(r)/r >= 0 for the Wendland kernels and the cubic spline).

    Morris: 2 sum_j V F_j (1 - cos k.x_j); pi_ij: the largest eigenvalue of 2 (d + 2) sum_j V F_j
    (1 - cos k.x_j) e_j e_j^T (e_j = x_j / |x_j|), over k in [0, pi / dx]^d (the symbols are even in each
    component of k)."""
    offsets, r, weight = lattice_offsets(kernel, dim, dx)
    e = offsets / r[:, None]

    def largest(k):
        c = (1.0 - np.cos(k @ offsets.T)) * weight  # (wave, neighbour)
        if morris:
            return 2.0 * c.sum(axis=1)
        return np.linalg.eigvalsh(2.0 * (dim + 2) * np.einsum("kj,ja,jb->kab", c, e, e))[:, -1]

    diagonal = weight.sum() if morris else np.linalg.eigvalsh(np.einsum("j,ja,jb->ab", weight, e, e))[-1]
    return zone_maximum(largest, dim, np.pi / dx), float(diagonal)


class ViscousLimit:
    """dt <= SAFETY reach / (nu lambda), lambda = the lattice's lambda_max scaled by the fluid particles'
    largest diagonal weight over the lattice's (all ranks). The scaling costs one pass over the pairs, made
    only when the lattice's own limit comes within BOTHER of the CFL step (a flow at moderate Reynolds number
    never pays it)."""

    BOTHER = 4.0

    def __init__(self, kernel, dim: int, dx: float, nu: float, morris: bool, integrator: str, walls=None):
        """walls: the scheme's boundaries.clone.WallTerms, whose no-slip clones weigh a row's velocity more than
        a fluid neighbour does (WallTerms.viscous_weight), or None."""
        self.nu, self.morris, self.walls = nu, morris, NO_WALLS if walls is None else walls
        self.lattice, self.diagonal = lattice_symbol(kernel, dim, dx, morris)
        self.step = SAFETY * REAL_AXIS_REACH[integrator] / (nu * self.lattice) if nu > 0.0 else np.inf

    @classmethod
    def of_scene(cls, scene, scheme, kernel):
        """The limit of `scene` run with `scheme` (its nu, operator and walls) and `kernel`."""
        return cls(kernel, scene.domain.dimension, scene.domain.dx, scheme.nu, scheme.morris, scene.time.integrator,
                   scheme.walls)

    def __call__(self, system, dt_cfl: float, t: float) -> float:
        """The viscous limit on the step of `system` at time t now, or inf where it cannot bind. Collective."""
        if self.step >= self.BOTHER * dt_cfl:
            return np.inf
        p = system.particles
        rows = np.flatnonzero(fluid_mask(system))
        extra = self.walls.viscous_weight(system, rows, t, not self.morris)
        local = largest_kernel_factor_sum(p["position"], p["volume"], system.nbr_ptr, system.nbr_idx,
                                          system.kernel.params, rows, not self.morris, extra)
        spread = max(1.0, allreduce_max(system.comm, local) / self.diagonal)
        return self.step / spread
