"""Explicit Runge-Kutta time integrators over a scheme's state (dicts of per-particle arrays).

Kutta RK3 (thesis 000 eq. 5.51, last stage corrected as in seeds/README.md):
    Psi2 = Psi^n + dt/2 H1,  Psi3 = Psi^n - dt H1 + 2 dt H2,  Psi^{n+1} = Psi^n + dt (H1/6 + 2 H2/3 + H3/6)
classical RK4:
    Psi^{n+1} = Psi^n + dt/6 (H1 + 2 H2 + 2 H3 + H4)
tests/schemes/test_integrators.py checks their orders on a linear ODE.

Within a step particles move by less than the neighbour lists' remaining skin (the driver rebuilds before
the step when needed), so stages only refresh halo positions and the particle order is fixed.
"""


def _combine(base, terms):
    return {k: base[k] + sum(c * h[k] for c, h in terms) for k in base}


def kutta_rk3(scheme, system, t, dt):
    y0 = scheme.state(system)
    h1 = scheme.rhs(system, t, dt)
    scheme.set_state(system, _combine(y0, [(0.5 * dt, h1)]))
    h2 = scheme.rhs(system, t + 0.5 * dt, dt)
    scheme.set_state(system, _combine(y0, [(-dt, h1), (2.0 * dt, h2)]))
    h3 = scheme.rhs(system, t + dt, dt)
    scheme.set_state(system, _combine(y0, [(dt / 6.0, h1), (2.0 * dt / 3.0, h2), (dt / 6.0, h3)]))


def rk4(scheme, system, t, dt):
    y0 = scheme.state(system)
    h1 = scheme.rhs(system, t, dt)
    scheme.set_state(system, _combine(y0, [(0.5 * dt, h1)]))
    h2 = scheme.rhs(system, t + 0.5 * dt, dt)
    scheme.set_state(system, _combine(y0, [(0.5 * dt, h2)]))
    h3 = scheme.rhs(system, t + 0.5 * dt, dt)
    scheme.set_state(system, _combine(y0, [(dt, h3)]))
    h4 = scheme.rhs(system, t + dt, dt)
    scheme.set_state(system, _combine(y0, [(dt / 6.0, h1), (dt / 3.0, h2), (dt / 3.0, h3), (dt / 6.0, h4)]))


INTEGRATORS = {"rk3": kutta_rk3, "rk4": rk4}
# how far past the step's start a stage may place a particle, in units of dt max|u + du|
STAGE_REACH = {"rk3": 3.0, "rk4": 1.0}
