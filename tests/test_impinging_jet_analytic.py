"""The wall solution of a 2-D jet impinging normally on a flat plate (analytic.impinging_jet_wall) is checked
against its hodograph derivation: symbolically (the chain of maps gives dx/dq on the plate and the momentum
balance), numerically (the free streamline has the jet's half-width upstream and the wall jet's thickness
downstream), and through the properties of the function itself."""

import numpy as np
import pytest
import sympy as sp
from scipy.integrate import quad

from psph.analytic import impinging_jet_wall

H, U, RHO = 0.7, 2.3, 1.3  # not 1, so that a missing scale factor shows


def _x_of_q(q, H=H):
    """The plate abscissa of the wall speed u = U q (the derivation in impinging_jet_wall's docstring)."""
    return 4.0 * H / np.pi * (np.arctanh(q) + np.arctan(q))


def test_hodograph_maps_give_the_wall_formula():
    """zeta = (u - i v) / U, t = zeta^2, sigma = -(t + 1/t) / 2, w = (U H / pi) ln((sigma - 1) / (sigma + 1)):
    dz/dzeta = (dw/dzeta) / (U zeta) = (8 H / pi) / (1 - zeta^4), so on the plate (zeta = q real)
    dx/dq = (8 H / pi) / (1 - q^4), whose integral from the stagnation point is (4 H / pi)(artanh q + arctan q).
    On the plate w is real (psi = 0), and the force on half the plate, int p dx = rho U^2 H, is half the jet's
    momentum flux 2 rho U^2 H, all turned parallel to the plate (symbolic)."""
    zeta, q, Hs, Us, rho = sp.symbols("zeta q H U rho", positive=True)
    t = zeta**2
    sigma = -(t + 1 / t) / 2
    w = Us * Hs / sp.pi * sp.log((sigma - 1) / (sigma + 1))
    dz_dzeta = sp.diff(w, zeta) / (Us * zeta)
    # every difference below is a rational function: cancel() reduces it to 0 only if it vanishes identically
    assert sp.cancel(dz_dzeta - 8 * Hs / sp.pi / (1 - zeta**4)) == 0
    dx_dq = dz_dzeta.subs(zeta, q)
    x = 4 * Hs / sp.pi * (sp.atanh(q) + sp.atan(q))
    assert sp.cancel(sp.diff(x, q) - dx_dq) == 0
    assert x.subs(q, 0) == 0
    # on the plate the argument of the log is ((1 + q^2) / (1 - q^2))^2 > 0: psi = 0 there
    assert sp.cancel((sigma - 1) / (sigma + 1) - ((1 + zeta**2) / (1 - zeta**2)) ** 2) == 0
    # momentum: int_0^inf p dx = int_0^1 rho U^2 (1 - q^2) / 2 dx/dq dq = rho U^2 H
    force = sp.integrate(sp.cancel(rho * Us**2 * (1 - q**2) / 2 * 8 * Hs / sp.pi / (1 - q**4)), (q, 0, 1))
    assert sp.simplify(force - rho * Us**2 * Hs) == 0
    # the thesis' eq. 3.3 as printed, at normal impact (phi = 0): u = 2 / (1 - q) > 1, so p < 0 on the plate
    phi = 0
    u_printed = (sp.sqrt((1 - q**2) * sp.sin(phi)) - 1 - sp.cos(phi)) / (q - sp.cos(phi))
    assert sp.simplify(u_printed - 2 / (1 - q)) == 0
    assert u_printed.subs(q, sp.Rational(1, 2)) > 1


def _dz_dzeta(zeta):
    """dz/dzeta = (dw/dsigma)(dsigma/dt)(dt/dzeta) / (U zeta), by the chain rule through the maps of the brief
    (not the simplified closed form), with dw/dsigma = (U H / pi) 2 / (sigma^2 - 1)."""
    t = zeta * zeta
    sigma = -0.5 * (t + 1.0 / t)
    dw_dsigma = U * H / np.pi * 2.0 / (sigma * sigma - 1.0)
    dsigma_dt = -0.5 * (1.0 - 1.0 / (t * t))
    return dw_dsigma * dsigma_dt * 2.0 * zeta / (U * zeta)


def _w(zeta):
    t = zeta * zeta
    sigma = -0.5 * (t + 1.0 / t)
    return U * H / np.pi * np.log((sigma - 1.0) / (sigma + 1.0))


def _z_on_ray(zeta_end, n=80):
    """z(zeta_end) = int_0^1 dz/dzeta(s zeta_end) zeta_end ds (z = 0 at the stagnation point zeta = 0)."""
    s, weights = np.polynomial.legendre.leggauss(n)
    s = 0.5 * (s + 1.0)
    return 0.5 * np.sum(weights * _dz_dzeta(s * zeta_end)) * zeta_end


def _z_on_free_streamline(theta_pole, eps, theta_start=0.25 * np.pi, n=200):
    """z(e^{i theta}) at theta = theta_pole -/+ eps (theta_pole = pi/2 upstream, 0 downstream): along the ray to
    e^{i theta_start}, then along the free streamline |zeta| = 1. dz/dtheta ~ 1 / (theta - theta_pole) near the
    pole, so the arc is integrated in tau = ln|theta - theta_pole|, where the integrand is smooth (Gauss-Legendre)."""
    side = np.sign(theta_start - theta_pole)
    tau_a, tau_b = np.log(abs(theta_start - theta_pole)), np.log(eps)
    nodes, weights = np.polynomial.legendre.leggauss(n)
    tau = 0.5 * (tau_a + tau_b) + 0.5 * (tau_b - tau_a) * nodes
    theta = theta_pole + side * np.exp(tau)
    zeta = np.exp(1j * theta)
    dz_dtau = _dz_dzeta(zeta) * 1j * zeta * side * np.exp(tau)
    return _z_on_ray(np.exp(1j * theta_start)) + 0.5 * (tau_b - tau_a) * np.sum(weights * dz_dtau)


def test_free_streamline_has_the_jet_and_wall_jet_widths():
    """Numerically, with H = 0.7 and U = 2.3: integrating dz = dw / (U zeta) from the stagnation point, the
    free streamline zeta = e^{i theta} tends to x = H upstream (theta -> pi/2: the jet's half-width) and to
    y = H downstream (theta -> 0: the wall jet's thickness, by mass conservation U H); psi = U H on it, psi = 0
    on the plate and the axis, and the plate (zeta = q) lies on y = 0 at the abscissa impinging_jet_wall
    inverts. A wrong constant in w (2 H / pi for U H / pi, say) moves both limits."""
    eps = 1e-6
    upstream = _z_on_free_streamline(0.5 * np.pi, eps)
    downstream = _z_on_free_streamline(0.0, eps)
    assert abs(upstream.real - H) < 1e-5 * H and upstream.imag > 5.0 * H
    assert abs(downstream.imag - H) < 1e-5 * H and downstream.real > 5.0 * H
    # streamlines: psi = U H on the free streamline, 0 on the plate and the axis; phi grows downstream. On
    # |zeta| = 1 sigma is real and the log sits on its branch cut, so psi is taken just inside the flow.
    theta = np.linspace(0.01, 0.5 * np.pi - 0.01, 50)
    w_free = _w((1.0 - 1e-10) * np.exp(1j * theta))
    assert np.allclose(w_free.imag, U * H, rtol=1e-8)
    assert np.all(np.diff(w_free.real) < 0.0)
    s = np.linspace(0.01, 0.99, 50)
    assert np.abs(_w(s + 0j).imag).max() < 1e-13 and np.abs(_w(1j * s).imag).max() < 1e-13
    # the maps take the flow (quarter disc) onto the upper sigma half plane
    rng = np.random.default_rng(0)
    zeta = np.sqrt(rng.uniform(0.0, 1.0, 200)) * np.exp(0.5j * np.pi * rng.uniform(0.0, 1.0, 200))
    assert np.all((-0.5 * (zeta**2 + zeta**-2)).imag > 0.0)
    # the plate and the axis: x(q) on y = 0, as impinging_jet_wall inverts it; x = 0 on the axis
    for q in (0.2, 0.6, 0.9):
        z = _z_on_ray(q + 0j)
        assert abs(z.imag) < 1e-13 and abs(z.real - _x_of_q(q)) < 1e-12
        u, p = impinging_jet_wall(z.real, H=H, U=U, rho=RHO)
        assert abs(u - U * q) < 1e-12 * U and abs(p - 0.5 * RHO * U**2 * (1.0 - q * q)) < 1e-12 * RHO * U**2
        assert abs(_z_on_ray(1j * q).real) < 1e-13


def test_wall_speed_and_pressure_properties():
    """impinging_jet_wall: stagnation pressure rho U^2 / 2 at x = 0, pressure falling and speed rising in |x|,
    symmetric in x, p -> 0 and u -> U far away, x(q) inverted to 1e-12, the plate force equal to the momentum
    flux, shape kept, and a non-positive half-width rejected."""
    u0, p0 = impinging_jet_wall(0.0, H=H, U=U, rho=RHO)
    assert u0 == 0.0 and p0 == 0.5 * RHO * U**2
    x = np.linspace(0.0, 20.0 * H, 2001)
    u, p = impinging_jet_wall(x, H=H, U=U, rho=RHO)
    assert np.all(np.diff(p) < 0.0) and np.all(p > 0.0)
    assert np.all(np.diff(u[x <= 10.0 * H]) > 0.0) and np.all(u < U * (1.0 + 1e-15))
    um, pm = impinging_jet_wall(-x, H=H, U=U, rho=RHO)
    assert np.array_equal(um, u) and np.array_equal(pm, p)
    u_far, p_far = impinging_jet_wall(np.array([30.0 * H, 1e6 * H, np.inf]), H=H, U=U, rho=RHO)
    assert np.all(np.abs(u_far - U) <= 1e-15 * U) and np.all(p_far < 1e-15 * RHO * U**2)
    # round trip: x(q) from the formula, back to u = U q
    q = np.concatenate([np.linspace(0.0, 0.999, 1000), 1.0 - np.logspace(-3, -12, 50)])
    u, p = impinging_jet_wall(_x_of_q(q), H=H, U=U, rho=RHO)
    assert np.abs(u / U - q).max() < 1e-12
    assert np.abs(p - 0.5 * RHO * U**2 * (1.0 - q) * (1.0 + q)).max() < 1e-12 * RHO * U**2
    # half the jet's momentum flux, 2 rho U^2 H, lands on each half of the plate
    force = quad(lambda xi: float(impinging_jet_wall(xi, H=H, U=U, rho=RHO)[1]), 0.0, 40.0 * H,
                 limit=200, epsabs=1e-13, epsrel=1e-12)[0]
    assert abs(force - RHO * U**2 * H) < 1e-9 * RHO * U**2 * H
    # the scales: u / U and p / (rho U^2) depend on x / H only
    u1, p1 = impinging_jet_wall(x / H)
    u_scaled, p_scaled = impinging_jet_wall(x, H=H, U=U, rho=RHO)
    assert np.allclose(u_scaled, U * u1, rtol=1e-13, atol=0) and np.allclose(p_scaled, RHO * U**2 * p1, rtol=1e-12)
    u2, p2 = impinging_jet_wall(np.ones((2, 3)), H=H)
    assert u2.shape == p2.shape == (2, 3)
    for bad in (0.0, -1.0, np.nan):
        with pytest.raises(ValueError, match="half-width"):
            impinging_jet_wall(1.0, H=bad)
