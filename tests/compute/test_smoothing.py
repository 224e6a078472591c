"""Kernels: normalisation by quadrature, derivatives against finite differences and sympy, misprints."""

import numpy as np
import pytest
from scipy import integrate

from psph.compute.smoothing import KERNEL_NAMES, make_kernel, normalisation

H = 0.37


@pytest.mark.parametrize("name", KERNEL_NAMES)
@pytest.mark.parametrize("dim", [1, 2, 3])
def test_normalisation_by_quadrature(name, dim):
    k = make_kernel(name, dim, H)
    w = lambda r: float(k.value(np.array([r]))[0])  # noqa: E731
    shell = {1: lambda r: 2.0 * w(r), 2: lambda r: 2.0 * np.pi * r * w(r), 3: lambda r: 4.0 * np.pi * r * r * w(r)}
    breaks = [H] if name == "cubic_spline" else None
    total, err = integrate.quad(shell[dim], 0.0, k.support, epsabs=1e-13, epsrel=1e-13, limit=200, points=breaks)
    assert abs(total - 1.0) < 1e-10


@pytest.mark.parametrize("name", KERNEL_NAMES)
def test_compact_support_and_positivity(name):
    k = make_kernel(name, 2, H)
    r = np.linspace(0.0, 3.0 * H, 301)
    w = k.value(r)
    assert np.all(w[r >= k.support] == 0.0)
    assert np.all(w[r < k.support * 0.999] > 0.0)
    assert np.all(np.diff(w) <= 1e-15)  # monotonically decreasing


@pytest.mark.parametrize("name", KERNEL_NAMES)
@pytest.mark.parametrize("dim", [1, 2, 3])
def test_gradient_and_hessian_match_finite_differences(name, dim):
    k = make_kernel(name, dim, H)
    rng = np.random.default_rng(7)
    x = rng.uniform(-1.0, 1.0, (60, dim))
    x *= (rng.uniform(0.05, 1.95, 60) * H / np.linalg.norm(x, axis=1))[:, None]
    eps = 1e-6 * H
    grad = k.gradient(x)
    hess = k.hessian(x)
    for a in range(dim):
        e = np.zeros(dim)
        e[a] = eps
        fd_grad = (k.value(np.linalg.norm(x + e, axis=1)) - k.value(np.linalg.norm(x - e, axis=1))) / (2 * eps)
        fd_hess = (k.gradient(x + e) - k.gradient(x - e)) / (2 * eps)
        scale = np.abs(k.gradient(x)).max()
        assert np.abs(grad[:, a] - fd_grad).max() < 1e-7 * scale
        assert np.abs(hess[:, :, a] - fd_hess).max() < 1e-6 * np.abs(hess).max()
    assert np.allclose(hess, np.transpose(hess, (0, 2, 1)))


@pytest.mark.parametrize("name", [n for n in KERNEL_NAMES if n.startswith("wendland")])
def test_hessian_at_origin_is_isotropic_limit(name):
    k = make_kernel(name, 2, H)
    at0 = k.hessian(np.zeros((1, 2)))[0]
    near = k.hessian(np.array([[1e-7 * H, 0.0]]))[0]
    assert np.allclose(at0, near, rtol=1e-5)
    assert at0[0, 0] < 0.0 and at0[0, 1] == 0.0


def test_formulas_against_sympy():
    """The factored derivative polynomials in smoothing.py equal sympy's derivatives of the kernels."""
    import sympy as sp

    q = sp.symbols("q", positive=True)
    polys = {"wendland_c2": (1 - q) ** 4 * (4 * q + 1),
             "wendland_c4": (1 - q) ** 6 * (35 * q**2 + 18 * q + 3),
             "wendland_c6": (1 - q) ** 8 * (32 * q**3 + 25 * q**2 + 8 * q + 1)}
    for name, f in polys.items():
        k = make_kernel(name, 2, H)
        a = normalisation(name, 2) / H**2
        for qv in (0.0, 0.13, 0.5, 0.77, 0.99):
            r = qv * 2 * H
            expect_w = a * float(f.subs(q, qv))
            expect_d2 = a * float(sp.diff(f, q, 2).subs(q, qv)) / (2 * H) ** 2
            assert np.isclose(k.value(np.array([r]))[0], expect_w, rtol=1e-12, atol=1e-14)
            assert np.isclose(k.hessian(np.array([[r, 0.0]]))[0, 0, 0], expect_d2, rtol=1e-10, atol=1e-12)
        # the constants are those normalising the printed polynomial (C6: seeds/README.md misprint)
        for dim, measure in ((1, 2 * 2 * H), (2, 2 * sp.pi * (2 * H) ** 2), (3, 4 * sp.pi * (2 * H) ** 3)):
            integral = sp.integrate(f * q ** (dim - 1), (q, 0, 1)) * measure
            assert np.isclose(float(1 / integral), normalisation(name, dim) / H**dim, rtol=1e-14)


def test_hessian_coefficient_closed_forms_against_sympy():
    """kernel_b = (W'' - W'/r) / r^2, the coefficient of x x^T in HessW, in closed form, against sympy's exact
    derivatives of every kernel, on both pieces of the cubic spline and near r = 0 (where forming W'' - W'/r
    in floating point would lose digits), in 1-D, 2-D and 3-D."""
    import sympy as sp

    from psph.compute.smoothing import hessian_coefficients

    q = sp.symbols("q", positive=True)
    pieces = {"wendland_c2": [((1 - q) ** 4 * (4 * q + 1), 0, 1)],
              "wendland_c4": [((1 - q) ** 6 * (35 * q**2 + 18 * q + 3), 0, 1)],
              "wendland_c6": [((1 - q) ** 8 * (32 * q**3 + 25 * q**2 + 8 * q + 1), 0, 1)],
              "cubic_spline": [(1 - sp.Rational(3, 2) * q**2 + sp.Rational(3, 4) * q**3, 0, 1),
                               (sp.Rational(1, 4) * (2 - q) ** 3, 1, 2)]}
    for name, polys in pieces.items():
        for dim in (1, 2, 3):
            k = make_kernel(name, dim, H)
            per_r = k.params[3]  # q = r per_r
            for f, lo, hi in polys:
                b_q = sp.lambdify(q, sp.simplify((sp.diff(f, q, 2) - sp.diff(f, q) / q) / q**2), "mpmath")
                for qv in np.linspace(lo, hi, 7)[1:-1].tolist() + ([1e-4, 0.013] if lo == 0 else []):
                    r = qv / per_r
                    expect = normalisation(name, dim) / H**dim * per_r**4 * float(b_q(sp.Rational(qv)))
                    _, b = hessian_coefficients(r, k.params)
                    assert np.isclose(b, expect, rtol=1e-13, atol=0.0), (name, dim, qv, b, expect)
            at_zero = {"wendland_c4": 1680.0, "wendland_c6": 528.0}.get(name, 0.0)  # C2, cubic: b x x^T -> 0
            assert np.isclose(hessian_coefficients(0.0, k.params)[1], k.params[4] * per_r**2 * at_zero, rtol=1e-14)
            assert hessian_coefficients(1.001 * k.support, k.params) == (0.0, 0.0)
            assert all(np.isnan(hessian_coefficients(np.nan, k.params)))  # a NaN distance is not a zero weight


def test_c6_misprint_corrected():
    """Thesis eq. 4.29 prints 35 q^3 and 38/(14 pi): with those the 2-D kernel would not integrate to one."""
    assert np.isclose(normalisation("wendland_c6", 2), 39.0 / (14.0 * np.pi))
    assert np.isclose(normalisation("wendland_c6", 1), 15.0 / 16.0)


def test_invalid_arguments():
    with pytest.raises(ValueError, match="unknown kernel"):
        make_kernel("gauss", 2, 1.0)
    with pytest.raises(ValueError, match="dimension"):
        make_kernel("wendland_c2", 4, 1.0)
    with pytest.raises(ValueError, match="smoothing length"):
        make_kernel("wendland_c2", 2, 0.0)
