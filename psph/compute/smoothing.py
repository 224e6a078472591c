"""Smoothing kernels: value, gradient and Hessian (numba).

All kernels have compact support 2h (thesis 000, section 4.1.2). Wendland kernels use q = r / (2h) and
the same polynomial in 1-D, 2-D and 3-D; the cubic spline uses q = r / h (thesis eq. 4.25).

    Wendland C2  f(q) = (1-q)^4 (4q + 1)                      (thesis eq. 4.27)
    Wendland C4  f(q) = (1-q)^6 (35q^2 + 18q + 3)             (thesis eq. 4.28)
    Wendland C6  f(q) = (1-q)^8 (32q^3 + 25q^2 + 8q + 1)      (thesis eq. 4.29, corrected: 32, not 35)
    cubic spline f(q) = 1 - 3/2 q^2 + 3/4 q^3 (q < 1), 1/4 (2-q)^3 (1 <= q < 2)

W(r) = alpha_d / h^d f(q). The normalisation constants alpha_d below were derived symbolically and are
checked by quadrature to 1e-10 in tests/compute/test_smoothing.py. They differ from the thesis where the
thesis is misprinted: C6 (39/(14 pi), 15/16 in 1-D: seeds/README.md) and the 1-D constants of C2 and C4,
which the thesis takes from the genuinely 1-D Wendland functions (5/8, 3/4) instead of the polynomials it
prints; with the printed polynomials they are 3/4 and 9/32.

Compute kernels call three scalar functions of the distance r with the parameters kp of Kernel.params:

    kernel_w(r, kp)    W(r)
    kernel_f(r, kp)    W'(r) / r      so that  grad_i W_ij = f(r_ij) (x_i - x_j)  (finite at r = 0)
    kernel_b(r, kp)    (W''(r) - W'(r) / r) / r^2, in closed form (no cancellation, no division for C4, C6)

(an integer id rather than a function argument, because numba's on-disk cache does not recognise
function-typed arguments across processes)
and the Hessian of W at x is  H(x) = f I + b x x^T  with b = kernel_b (= f I at r = 0, see
hessian_coefficients()).
"""

from dataclasses import dataclass

import numpy as np
from numba import njit

# alpha_d for d = 1, 2, 3 (index d - 1); W = alpha_d / h^d f(q)
_NORMALISATION = {
    "wendland_c2": (3.0 / 4.0, 7.0 / (4.0 * np.pi), 21.0 / (16.0 * np.pi)),
    "wendland_c4": (9.0 / 32.0, 3.0 / (4.0 * np.pi), 165.0 / (256.0 * np.pi)),
    "wendland_c6": (15.0 / 16.0, 39.0 / (14.0 * np.pi), 1365.0 / (512.0 * np.pi)),
    "cubic_spline": (2.0 / 3.0, 10.0 / (7.0 * np.pi), 1.0 / np.pi),
}

KERNEL_NAMES = tuple(_NORMALISATION)


# Leaf functions of q: f(q), f'(q)/q and (f''(q) - f'(q)/q)/q^2 of each kernel's polynomial (zero beyond
# the support).
# The Wendland leaves clip 1 - q at zero instead of branching on q >= 1: the loops over neighbour lists then
# carry no unpredictable branch (a skin pair costs a few flops and adds exactly zero).
# LLVM inlines these leaves into every sum (the same machine code, checked with inspect_asm); numba's own
# inline="always" on them, applied to each of the four kernels at every call site, made the first compilation
# 2.5 times longer (227 against 90 s for the 2-D kernels, psph.compute.warmup). kernel_w, kernel_f and
# kernel_b keep it: without it some callers kept a call to them in their pair loops.
@njit(cache=True)
def _clip(t):
    """max(t, 0), NaN kept (a NaN distance must not turn into a zero weight)."""
    return 0.0 if t < 0.0 else t


# ---------------------------------------------------------------- Wendland C2
@njit(cache=True)
def _c2_w(q):
    t = _clip(1.0 - q)
    t2 = t * t
    return t2 * t2 * (4.0 * q + 1.0)


@njit(cache=True)
def _c2_fq(q):  # f'(q)/q = -20 (1-q)^3
    t = _clip(1.0 - q)
    return -20.0 * t * t * t


@njit(cache=True)
def _c2_bq(q):  # (f''(q) - f'(q)/q) / q^2 = 60 (1-q)^2 / q  (q > 0)
    t = _clip(1.0 - q)
    return 60.0 * t * t / q


# ---------------------------------------------------------------- Wendland C4
@njit(cache=True)
def _c4_w(q):
    t = _clip(1.0 - q)
    t2 = t * t
    return t2 * t2 * t2 * (35.0 * q * q + 18.0 * q + 3.0)


@njit(cache=True)
def _c4_fq(q):  # f'(q)/q = -56 (1-q)^5 (5q + 1)
    t = _clip(1.0 - q)
    t2 = t * t
    return -56.0 * t2 * t2 * t * (5.0 * q + 1.0)


@njit(cache=True)
def _c4_bq(q):  # (f''(q) - f'(q)/q) / q^2 = 1680 (1-q)^4
    t = _clip(1.0 - q)
    t2 = t * t
    return 1680.0 * t2 * t2


# ---------------------------------------------------------------- Wendland C6
@njit(cache=True)
def _c6_w(q):
    t = _clip(1.0 - q)
    t2 = t * t
    t4 = t2 * t2
    return t4 * t4 * (((32.0 * q + 25.0) * q + 8.0) * q + 1.0)


@njit(cache=True)
def _c6_fq(q):  # f'(q)/q = -22 (1-q)^7 (16q^2 + 7q + 1)
    t = _clip(1.0 - q)
    t2 = t * t
    t4 = t2 * t2
    return -22.0 * t4 * t2 * t * ((16.0 * q + 7.0) * q + 1.0)


@njit(cache=True)
def _c6_bq(q):  # (f''(q) - f'(q)/q) / q^2 = 528 (1-q)^6 (6q + 1)
    t = _clip(1.0 - q)
    t2 = t * t
    return 528.0 * t2 * t2 * t2 * (6.0 * q + 1.0)


# ---------------------------------------------------------------- cubic spline (q = r / h)
@njit(cache=True)
def _cubic_w(q):
    if q >= 2.0:
        return 0.0
    if q < 1.0:
        return 1.0 - 1.5 * q * q + 0.75 * q * q * q
    t = 2.0 - q
    return 0.25 * t * t * t


@njit(cache=True)
def _cubic_fq(q):  # 3/4 (3q - 4) for q < 1; -3/4 (2 - q)^2 / q for 1 <= q < 2
    if q >= 2.0:
        return 0.0
    if q < 1.0:
        return 0.75 * (3.0 * q - 4.0)
    t = 2.0 - q
    return -0.75 * t * t / q


@njit(cache=True)
def _cubic_bq(q):  # (f''(q) - f'(q)/q) / q^2 = 9 / (4q) for q < 1; 3/4 (4 - q^2) / q^3 for 1 <= q < 2  (q > 0)
    if q >= 2.0:
        return 0.0
    if q < 1.0:
        return 2.25 / q
    return 0.75 * (4.0 - q * q) / (q * q * q)


KERNEL_IDS = {"wendland_c2": 0, "wendland_c4": 1, "wendland_c6": 2, "cubic_spline": 3}


@njit(cache=True, inline="always")
def kernel_w(r, kp):
    """W(r) for kernel parameters kp = (kernel id, h, alpha_d / h^d, q per unit r, W'/r scale)."""
    q = r * kp[3]
    kid = kp[0]
    if kid == 2:
        return kp[2] * _c6_w(q)
    if kid == 0:
        return kp[2] * _c2_w(q)
    if kid == 1:
        return kp[2] * _c4_w(q)
    return kp[2] * _cubic_w(q)


@njit(cache=True, inline="always")
def kernel_f(r, kp):
    """W'(r) / r: grad_i W_ij = kernel_f(r_ij, kp) (x_i - x_j); finite at r = 0."""
    q = r * kp[3]
    kid = kp[0]
    if kid == 2:
        return kp[4] * _c6_fq(q)
    if kid == 0:
        return kp[4] * _c2_fq(q)
    if kid == 1:
        return kp[4] * _c4_fq(q)
    return kp[4] * _cubic_fq(q)


@njit(cache=True, inline="always")
def kernel_b(r, kp):
    """(W''(r) - W'(r) / r) / r^2, the coefficient of x x^T in HessW(x), from the factored polynomials
    (tests/compute/test_smoothing.py checks them with sympy): the difference is not formed, so nothing cancels
    near r = 0, and C4 and C6 need no division. It is finite at r = 0 for C4 and C6 and grows like 1 / r for
    C2 and the cubic spline, for which r = 0 gives 0 (the term b x x^T vanishes there). A NaN distance gives
    NaN."""
    q = r * kp[3]
    kid = kp[0]
    scale = kp[4] * kp[3] * kp[3]
    if kid == 2:
        return scale * _c6_bq(q)
    if kid == 1:
        return scale * _c4_bq(q)
    if q == 0.0:
        return 0.0
    if kid == 0:
        return scale * _c2_bq(q)
    return scale * _cubic_bq(q)


@njit(cache=True, inline="always")
def hessian_coefficients(r, kp):
    """(a, b) with HessW(x) = a I + b x x^T at |x| = r: a = W'(r) / r, b = kernel_b (b x x^T = 0 at r = 0,
    where HessW = a I)."""
    return kernel_f(r, kp), kernel_b(r, kp)


@njit(cache=True)
def _evaluate(which, r, kp):
    out = np.empty(r.size)
    flat = r.ravel()
    for k in range(flat.size):
        if which == 0:
            out[k] = kernel_w(flat[k], kp)
        elif which == 1:
            out[k] = kernel_f(flat[k], kp)
        else:
            out[k] = kernel_b(flat[k], kp)
    return out.reshape(r.shape)


@dataclass(frozen=True)
class Kernel:
    """A smoothing kernel bound to a dimension and a smoothing length.

    `params` = (kernel id, h, alpha_d / h^d, 1 / (2h) (1 / h for the cubic spline), alpha_d / h^d / (2h)^2)
    is what compute kernels take (kernel_w/f/b(r, params)); the precomputed scales spare the hot loops
    every division.
    The methods below evaluate on numpy arrays, for tests and set-up, not hot loops.
    """

    name: str
    dim: int
    h: float
    params: tuple

    @property
    def support(self) -> float:
        """Support radius 2h."""
        return 2.0 * self.h

    def value(self, r):
        """W(r) for an array of distances."""
        return _evaluate(0, np.asarray(r, dtype=np.float64), self.params)

    def radial(self, r):
        """W'(r)/r for an array of distances."""
        return _evaluate(1, np.asarray(r, dtype=np.float64), self.params)

    def gradient(self, x):
        """grad W(x) for displacement vectors x of shape (n, dim)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1, self.dim)
        return self.radial(np.sqrt((x * x).sum(axis=1)))[:, None] * x

    def hessian(self, x):
        """HessW(x) for displacement vectors x of shape (n, dim); returns (n, dim, dim)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1, self.dim)
        r = np.sqrt((x * x).sum(axis=1))
        a = self.radial(r)
        b = _evaluate(2, r, self.params)
        return a[:, None, None] * np.eye(self.dim) + b[:, None, None] * x[:, :, None] * x[:, None, :]


def normalisation(name: str, dim: int) -> float:
    """alpha_d of kernel `name` in `dim` dimensions (W = alpha_d / h^d f(q))."""
    return _NORMALISATION[name][dim - 1]


def make_kernel(name: str, dim: int, h: float) -> Kernel:
    """Kernel `name` (one of KERNEL_NAMES) in `dim` dimensions with smoothing length `h`."""
    if name not in _NORMALISATION:
        raise ValueError(f"unknown kernel {name!r}; choose one of {', '.join(KERNEL_NAMES)}")
    if dim not in (1, 2, 3):
        raise ValueError(f"dimension must be 1, 2 or 3, got {dim}")
    if not h > 0.0:
        raise ValueError(f"smoothing length must be > 0, got {h}")
    a = normalisation(name, dim) / h**dim
    per_r = 1.0 / h if name == "cubic_spline" else 1.0 / (2.0 * h)  # q = r * per_r
    params = (KERNEL_IDS[name], float(h), float(a), float(per_r), float(a * per_r * per_r))
    return Kernel(name=name, dim=dim, h=float(h), params=params)
