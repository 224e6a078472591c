"""Explicit Runge-Kutta time integrators over a scheme's state (dicts of per-particle arrays).

Kutta RK3 (thesis 000 eq. 5.51, last stage corrected as in seeds/README.md):
    Psi2 = Psi^n + dt/2 H1,  Psi3 = Psi^n - dt H1 + 2 dt H2,  Psi^{n+1} = Psi^n + dt (H1/6 + 2 H2/3 + H3/6)
classical RK4:
    Psi^{n+1} = Psi^n + dt/6 (H1 + 2 H2 + 2 H3 + H4)
tests/schemes/test_integrators.py checks their orders on a linear ODE.

Within a step the particle order is fixed and stages only refresh halo positions: the driver rebuilds the
neighbour lists before a step whose expected reach would take a particle past half the skin, and every
intermediate stage checks that none went further (system.check_lists raises ListsExpired; the driver then
rebuilds and takes the step again). The final state is the driver's to check (system.update).
"""


def _combine(base, terms):
    return {k: base[k] + sum(c * h[k] for c, h in terms) for k in base}


def _stage(scheme, system, state):
    """Move to an intermediate stage's state, whose right-hand side the neighbour lists must still hold."""
    scheme.set_state(system, state)
    system.check_lists()


def kutta_rk3(scheme, system, t, dt, y0=None):
    """y0: scheme.state(system) if the caller has it already."""
    y0 = scheme.state(system) if y0 is None else y0
    h1 = scheme.rhs(system, t, dt)
    _stage(scheme, system, _combine(y0, [(0.5 * dt, h1)]))
    h2 = scheme.rhs(system, t + 0.5 * dt, dt)
    _stage(scheme, system, _combine(y0, [(-dt, h1), (2.0 * dt, h2)]))
    h3 = scheme.rhs(system, t + dt, dt)
    scheme.set_state(system, _combine(y0, [(dt / 6.0, h1), (2.0 * dt / 3.0, h2), (dt / 6.0, h3)]))


def rk4(scheme, system, t, dt, y0=None):
    """y0: scheme.state(system) if the caller has it already."""
    y0 = scheme.state(system) if y0 is None else y0
    h1 = scheme.rhs(system, t, dt)
    _stage(scheme, system, _combine(y0, [(0.5 * dt, h1)]))
    h2 = scheme.rhs(system, t + 0.5 * dt, dt)
    _stage(scheme, system, _combine(y0, [(0.5 * dt, h2)]))
    h3 = scheme.rhs(system, t + 0.5 * dt, dt)
    _stage(scheme, system, _combine(y0, [(dt, h3)]))
    h4 = scheme.rhs(system, t + dt, dt)
    scheme.set_state(system, _combine(y0, [(dt / 6.0, h1), (dt / 3.0, h2), (dt / 3.0, h3), (dt / 6.0, h4)]))


INTEGRATORS = {"rk3": kutta_rk3, "rk4": rk4}
# how far past the step's start a stage is expected to place a particle, in units of dt max|u + du| at the
# step's start: about one step's travel (RK3's third stage, y0 - dt H1 + 2 dt H2, goes as far as the others
# unless the velocity changes within the step; 3 would bound it for any change, and made a rebuild at almost
# every step of the inclined ellipse); the margin is for the change within the step. A stage that goes
# further is caught (system.check_lists) and the step taken again after a rebuild.
STAGE_REACH = {"rk3": 1.25, "rk4": 1.25}
