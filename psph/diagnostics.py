"""Particle-distribution and interpolation-accuracy diagnostics (collective: they reduce over ranks).

L2(grad C)   = h sqrt(sum_i |grad C_i|^2 / n)          thesis eq. 3.4
Linf(grad C) = h max_i |grad C_i|                      thesis eq. 3.5
L2(d f/dx)   = sqrt(sum_i (d_x f_i^SPH - d_x f_i)^2 / n) thesis eq. 3.7, plain SPH gradient (eq. 4.31)

with the test function (thesis eq. 3.6, written with its wavelength l, see DiagnosticsSpec)
f = sin(2 pi x / l) + cos(2 pi y / l). Sums run over FLUID particles.
"""

import numpy as np

from psph.compute import sums
from psph.parallel.comm import allreduce_max, allreduce_sum
from psph.particles import Kind


def grad_c(system, volume="volume") -> np.ndarray:
    """grad C of the owned particles, C_i = sum_j W_ij V_j with V the field `volume` (the particle volumes,
    or the reference volumes "volume0" that IIPS + NFTS levels; the halo positions and volumes must be
    current)."""
    p = system.particles
    k = system.kernel
    out = np.zeros((p.n_owned, p.dim))
    sums.grad_concentration(p["position"], p[volume], system.nbr_ptr, system.nbr_idx, k.params, out)
    return out


def fluid_mask(system) -> np.ndarray:
    return system.particles.owned("kind") == Kind.FLUID


def norms(comm, values: np.ndarray, mask: np.ndarray, scale: float = 1.0) -> tuple:
    """(scale * RMS, scale * max) of |values| over the masked rows of all ranks. Collective."""
    v = values[mask]
    mag2 = np.sum(v * v, axis=tuple(range(1, v.ndim)))
    total = allreduce_sum(comm, np.array([mag2.sum(), float(len(v))]))
    peak = allreduce_max(comm, float(np.sqrt(mag2.max())) if len(v) else 0.0)
    rms = np.sqrt(total[0] / total[1]) if total[1] > 0 else 0.0
    return scale * rms, scale * peak


def test_function(pos: np.ndarray, wavelength: float):
    """(f, d f/dx) of the test function at `pos`."""
    k = 2.0 * np.pi / wavelength
    f = np.sin(k * pos[:, 0])
    if pos.shape[1] > 1:
        f = f + np.cos(k * pos[:, 1])
    return f, k * np.cos(k * pos[:, 0])


def dfdx_sph(system, wavelength: float) -> np.ndarray:
    """Plain SPH x-derivative of the test function at the owned particles."""
    p = system.particles
    k = system.kernel
    f, _ = test_function(p["position"], wavelength)
    out = np.zeros((p.n_owned, p.dim))
    sums.gradient(p["position"], p["volume"], system.nbr_ptr, system.nbr_idx, k.params, f, out)
    return out[:, 0]


def distribution_report(system, wavelength: float, grad=None) -> dict:
    """L2_grad_c, Linf_grad_c and L2_dfdx of the current distribution. Collective."""
    if grad is None:
        grad = grad_c(system)
    mask = fluid_mask(system)
    l2, linf = norms(system.comm, grad, mask, system.kernel.h)
    exact = test_function(system.particles.owned("position"), wavelength)[1]
    err = dfdx_sph(system, wavelength) - exact
    l2_dfdx, _ = norms(system.comm, err, mask)
    return {"L2_grad_c": l2, "Linf_grad_c": linf, "L2_dfdx": l2_dfdx}


def shepard_sums(kernel, pos, values, volumes, probes, domain=None) -> tuple:
    """(sum_j phi_j W(x_k - x_j) V_j, sum_j W(x_k - x_j) V_j) over the particles given and, with `domain`,
    their periodic images, for every probe x_k: the numerator (of the shape of phi's rows) and denominator
    of the Shepard interpolation phi(x_k), to be added over ranks. Local."""
    from scipy.spatial import cKDTree

    num = np.zeros((len(probes),) + values.shape[1:])
    den = np.zeros(len(probes))
    if len(pos) == 0:
        return num, den
    if domain is not None and any(domain.periodic):
        # (an audit: without the images, probes at y = 0 and y = 1 of a periodic shear read +0.22 and -0.22)
        probes = np.array(probes, dtype=np.float64)
        domain.wrap(probes)
        pos, rows = domain.with_images(pos, kernel.support)
        values, volumes = values[rows], volumes[rows]
    for k, js in enumerate(cKDTree(pos).query_ball_point(probes, kernel.support)):
        if js:
            w = kernel.value(np.linalg.norm(pos[js] - probes[k], axis=1)) * volumes[js]
            num[k], den[k] = np.tensordot(w, values[js], axes=1), w.sum()
    return num, den


def interpolate_fluid(system, values, points) -> np.ndarray:
    """Shepard interpolation at `points` of the owned rows' `values` (rows of any shape) over the fluid
    particles of every rank (shepard_sums, summed over the ranks: independent of their number); nan where
    no fluid lies within a kernel support. Collective."""
    p = system.particles
    mask = fluid_mask(system)
    num, den = shepard_sums(system.kernel, p.owned("position")[mask], values[mask], p.owned("volume")[mask], points,
                            system.domain)
    flat = num.reshape(len(points), -1)
    total = allreduce_sum(system.comm, np.concatenate([flat, den[:, None]], axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return (total[:, :-1] / total[:, -1:]).reshape(num.shape)
