"""Analytic fields used as initial conditions and references.

Taylor-Green vortex in a bi-periodic square of side L (thesis 000 eq. 3.1 with its sign misprint
corrected, consistent with eq. 8.33; seeds/README.md):
    u = -U e^{-8 pi^2 t / Re} cos(2 pi x / L) sin(2 pi y / L)
    v = +U e^{-8 pi^2 t / Re} sin(2 pi x / L) cos(2 pi y / L)
    p = -rho U^2 / 4 e^{-16 pi^2 t / Re} [cos(4 pi x / L) + cos(4 pi y / L)]
with Re = U L / nu and t in units of L / U (the functions take dimensional t and scale it by U / L).
The pressure sign is the opposite of the thesis' (eq. 3.1):
with the corrected velocity, only this sign balances the momentum equation. tests/test_analytic.py checks
symbolically that (u, v, p) solve the incompressible Navier-Stokes equations for any U, L, rho, Re.

Elliptical drop (seed 002 section 3.4, eq. 3.19-3.20; Monaghan 1994): see EllipticalDrop.

Jet impinging normally on an infinite flat plate (Michell 1890, Taylor 1966; thesis 000 eq. 3.3, misprinted
there): see impinging_jet_wall.

Dam break (seed 001 section 6.3): the pressure and acceleration of the incompressible fluid at the instant the
dam is removed, see dam_break_initial.
"""

import numpy as np


def taylor_green(pos, t=0.0, *, U=1.0, L=1.0, rho=1.0, reynolds=np.inf, lower=(0.0, 0.0)):
    """(velocity (n, 2), pressure (n,)) of the Taylor-Green vortex at `pos` and time t."""
    x = 2.0 * np.pi * (pos[:, 0] - lower[0]) / L
    y = 2.0 * np.pi * (pos[:, 1] - lower[1]) / L
    decay = np.exp(-8.0 * np.pi**2 * t * U / (L * reynolds)) if np.isfinite(reynolds) else 1.0
    u = -U * decay * np.cos(x) * np.sin(y)
    v = U * decay * np.sin(x) * np.cos(y)
    p = -0.25 * rho * U**2 * decay**2 * (np.cos(2.0 * x) + np.cos(2.0 * y))
    return np.stack([u, v], axis=1), p


def taylor_green_kinetic_energy(t, *, U=1.0, L=1.0, rho=1.0, reynolds=np.inf):
    """E_k(t) = rho U^2 L^2 / 4 e^{-16 pi^2 t U / (L Re)} of the whole square (thesis eq. 3.2)."""
    decay = np.exp(-16.0 * np.pi**2 * t * U / (L * reynolds)) if np.isfinite(reynolds) else 1.0
    return 0.25 * rho * U**2 * L**2 * decay


def couette_startup(y, t, *, U=1.0, H=1.0, nu=1.0, terms=200):
    """Start-up Couette flow between a plate at rest (y = 0) and one set moving at U at t = 0 (y = H):
        u(y, t) = U y / H + sum_n 2 U (-1)^n / (n pi) sin(n pi y / H) exp(-nu n^2 pi^2 t / H^2),
    the separation-of-variables solution of u_t = nu u_yy with u(0) = 0, u(H) = U, u(y, 0) = 0 (the
    series of y / H cancels the steady part at t = 0). tests/test_analytic.py checks the equation, the
    boundary and the initial conditions."""
    y = np.asarray(y, float)
    n = np.arange(1, terms + 1)[:, None]
    series = 2.0 * U * (-1.0) ** n / (n * np.pi) * np.sin(n * np.pi * y / H) * np.exp(-nu * (n * np.pi / H) ** 2 * t)
    return U * y / H + series.sum(axis=0)


def dam_break_initial(pos, *, H=1.0, B=2.0, rho=1.0, g=1.0, terms=400):
    """(p (n,), a (n, 2)) at the points pos of a column of fluid H deep and B long, between a wall at x = 0 and
    a bottom at y = 0, at rest under gravity g along -y, at the instant its dam (x = B) is removed: the
    incompressible fluid's initial pressure and acceleration a = -grad p / rho - g e_y (the impulsive start of
    a dam break; the problem of Pohle 1950). Starting from rest, du/dt = -grad p / rho + g with div u = 0 makes
    p harmonic, with grad p . n = rho g . n on the walls and p = 0 on the free surfaces y = H and x = B.
    The hydrostatic rho g (H - y) meets all but x = B; the series
        p = rho g (H - y) - sum_n a_n cos(k_n y) cosh(k_n x) / cosh(k_n B),   k_n = (2 n + 1) pi / (2 H),
        a_n = (2 / H) int_0^H rho g (H - y) cos(k_n y) dy = 2 rho g / (H k_n^2)
    cancels it there term by term (each term is harmonic, has no normal derivative at x = 0 or y = 0, and
    vanishes at y = H). tests/test_analytic.py checks the equation and the four boundary conditions. The
    pressure is continuous; the acceleration grows like log(1/r) at the corner (B, 0) where the free face
    meets the bottom (the series of a_x converges slowly there). nan outside the column 0 <= x <= B, 0 <= y <= H."""
    pos = np.asarray(pos, float)
    inside = (pos[:, 0] >= 0.0) & (pos[:, 0] <= B) & (pos[:, 1] >= 0.0) & (pos[:, 1] <= H)
    x, y = np.where(inside, pos[:, 0], 0.0)[None, :], np.where(inside, pos[:, 1], 0.0)[None, :]
    k = ((2 * np.arange(terms) + 1) * np.pi / (2.0 * H))[:, None]
    a = 2.0 * rho * g / (H * k * k)
    # cosh(k x) / cosh(k B) and sinh(k x) / cosh(k B), written without overflow for large k B
    decay = np.exp(k * (x - B)) / (1.0 + np.exp(-2.0 * k * B))
    ch, sh = decay * (1.0 + np.exp(-2.0 * k * x)), decay * (1.0 - np.exp(-2.0 * k * x))
    cos, sin = np.cos(k * y), np.sin(k * y)
    p = rho * g * (H - y[0]) - (a * cos * ch).sum(axis=0)
    acc = np.empty((len(pos), 2))
    acc[:, 0] = (a * k * cos * sh).sum(axis=0) / rho
    acc[:, 1] = -(a * k * sin * ch).sum(axis=0) / rho  # the hydrostatic part's -grad p / rho cancels g
    p[~inside], acc[~inside] = np.nan, np.nan
    return p, acc


def impinging_jet_wall(x, H=1.0, U=1.0, rho=1.0):
    """(u (n,), p (n,)) on the plate y = 0 of a 2-D jet of half-width H and speed U impinging normally on it,
    at abscissae x from the jet axis (any sign; the flow is symmetric in x). Inviscid, steady, free streamlines
    at p = 0 (Michell 1890; Taylor 1966). Source: thesis 000 eq. 3.3 (misprinted there; derived here by the
    hodograph method): at phi = 0 the printed u = 2 / (1 - q) exceeds U.

    Derivation (x > 0 half): zeta = (u - i v) / U maps the flow onto the quarter unit disc (plate: zeta = q
    real in [0, 1); axis: zeta = i s; free streamline: |zeta| = 1; upstream zeta = i, downstream zeta = 1,
    stagnation zeta = 0); t = zeta^2 and sigma = -(t + 1/t) / 2 take it onto the upper half plane, where
        w = (U H / pi) ln((sigma - 1) / (sigma + 1)) = (2 U H / pi) ln((1 + zeta^2) / (1 - zeta^2))
    has psi = 0 on the axis and the plate and psi = U H on the free streamline; dz = dw / (U zeta) gives
    z = (4 H / pi) (artanh zeta + arctan zeta), so on the plate
        x / H = (4 / pi) (artanh q + arctan q),   u = U q,   p = rho U^2 (1 - q^2) / 2,
    the free streamline tends to x = H upstream and to y = H downstream (wall jets of thickness H), and the
    force on the plate is 2 rho U^2 H, the jet's momentum flux (tests/test_impinging_jet_analytic.py).

    x(q) is inverted with q = tanh(a): c := pi |x| / (4 H) = a + arctan(tanh a) =: g(a), g concave with
    1 < g' <= 2, so Newton from the lower bound max(c / 2, c - pi / 4) rises monotonically to the root, and
    p = rho U^2 / 2 sech^2(a) keeps its relative accuracy far from the axis. Units: those of H, U, rho
    (SI in psph); returns arrays of the shape of x; |x| = inf gives u = U, p = 0."""
    if not H > 0.0:
        raise ValueError(f"the jet half-width H = {H} must be positive")
    c = 0.25 * np.pi * np.abs(np.asarray(x, dtype=float)) / H
    finite = np.isfinite(c)
    target = np.where(finite, c, 0.0)  # Newton on finite x only; inf and nan pass through below
    a = np.maximum(0.5 * target, target - 0.25 * np.pi)
    for _ in range(50):
        step = (a + np.arctan(np.tanh(a)) - target) / (1.0 + 1.0 / np.cosh(np.minimum(2.0 * a, 700.0)))
        a = a - step
        if np.all(np.abs(step) <= 1e-15 * (1.0 + a)):
            break
    a = np.where(finite, a, c)
    e = np.exp(-2.0 * a)
    return U * np.tanh(a), 2.0 * rho * U**2 * e / (1.0 + e) ** 2


TAU_HORIZON = 10.0  # EllipticalDrop: A0 t the drop's ODE is integrated to at least


class EllipticalDrop:
    """An inviscid drop, at t = 0 a disc of radius R about `center` with u = A0 x, v = -A0 y and
    p = rho A0^2 / 2 (R^2 - x^2 - y^2) (x, y from the centre; seed 002 eq. 3.19-3.20), stays an ellipse
    x^2 / a^2 + y^2 / b^2 = 1 with the linear field u = A x, v = -A y and
        da/dt = A a,   db/dt = -A b,   dA/dt = A^2 (b^2 - a^2) / (a^2 + b^2),   a(0) = b(0) = R, A(0) = A0,
        p = rho / 2 [(A^2 + dA/dt) (a^2 - x^2) - (A^2 - dA/dt) y^2]
    (the momentum equation gives p up to a constant, and p = 0 on the ellipse fixes it and dA/dt; the area
    pi a b stays pi R^2). tests/test_analytic.py checks symbolically that this solves the Euler equations with
    p = 0 on a boundary that moves with the fluid. The ODE is integrated once, to t_end or A0 t = TAU_HORIZON
    (scipy, rtol 1e-12)."""

    def __init__(self, radius, a0, t_end, center=(0.0, 0.0), rho=1.0):
        from scipy.integrate import solve_ivp

        self.radius, self.a0, self.center, self.rho = radius, a0, np.asarray(center, dtype=float), rho

        def rhs(_, y):  # in a / R, b / R, A / A0 against tau = A0 t: the same for every drop
            a, b, A = y
            return [A * a, -A * b, _rate_change(a, b, A)]

        tau_end = abs(a0) * t_end
        if not np.isfinite(tau_end):
            raise ValueError(f"the drop's A0 t_end = {tau_end} is not finite")
        # to a horizon that does not move with t_end below it: the adaptive steps, and so the values at a given
        # time to the last bit, depended on where the integration ended (1e-14: a continuation that extended
        # t_end changed the reference columns of the rows before its checkpoint, a restarts audit)
        self._solution = solve_ivp(rhs, (0.0, max(tau_end, TAU_HORIZON)), [1.0, 1.0, np.sign(a0) or 1.0],
                                   method="DOP853", rtol=1e-12, atol=1e-14, dense_output=True).sol

    def state(self, t):
        """(a, b, A, dA/dt) at time t."""
        a, b, A = self._solution(abs(self.a0) * t) * [self.radius, self.radius, abs(self.a0)]
        return a, b, A, _rate_change(a, b, A)

    def fields(self, pos, t):
        """(velocity (n, 2), pressure (n,)) at `pos` and time t (inside the drop)."""
        a, b, A, dA = self.state(t)
        x, y = (pos[:, 0] - self.center[0]), (pos[:, 1] - self.center[1])
        p = 0.5 * self.rho * ((A * A + dA) * (a * a - x * x) - (A * A - dA) * y * y)
        return np.stack([A * x, -A * y], axis=1), p


def _rate_change(a, b, A):
    """dA/dt of the elliptical drop (EllipticalDrop)."""
    return A * A * (b * b - a * a) / (a * a + b * b)
