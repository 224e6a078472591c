"""Time integrators reach their orders (Kutta RK3 with the corrected last stage: 3; RK4: 4)."""

import numpy as np
import pytest

from psph.schemes.integrators import INTEGRATORS


class LinearODE:
    """dy/dt = A y with a rotation-plus-decay A; exact solution by the matrix exponential."""

    a = np.array([[-0.3, 2.0], [-2.0, -0.3]])

    def __init__(self):
        self.y = np.array([1.0, 0.5])

    def state(self, system):
        return {"y": self.y.copy()}

    def set_state(self, system, state):
        self.y = state["y"].copy()

    def rhs(self, system, t, dt):
        return {"y": self.a @ self.y}


class AnyStage:
    """A particle system whose neighbour lists hold every stage."""

    def check_lists(self):
        pass


@pytest.mark.parametrize("name,order", [("rk3", 3), ("rk4", 4)])
def test_order(name, order):
    from scipy.linalg import expm

    exact = expm(LinearODE.a * 1.0) @ np.array([1.0, 0.5])
    errors = []
    for n in (20, 40):
        ode = LinearODE()
        for k in range(n):
            INTEGRATORS[name](ode, AnyStage(), k / n, 1.0 / n)
        errors.append(np.abs(ode.y - exact).max())
    assert np.log2(errors[0] / errors[1]) == pytest.approx(order, abs=0.15)


def test_printed_rk3_last_stage_is_not_consistent():
    """Thesis eq. 5.51 as printed (dt on H1 only) is no consistent scheme: its step tends to (5/6) A y0, not
    to zero, as dt -> 0; psph's last stage (dt on every stage) takes the step of the exact solution."""
    ode = LinearODE()
    y0 = ode.y.copy()

    def printed_step(dt):
        h1 = ode.a @ y0
        h2 = ode.a @ (y0 + 0.5 * dt * h1)
        h3 = ode.a @ (y0 - dt * h1 + 2 * dt * h2)
        return dt * h1 / 6 + 2 * h2 / 3 + h3 / 6

    for dt in (1e-2, 1e-4):
        assert np.allclose(printed_step(dt), 5.0 / 6.0 * ode.a @ y0, rtol=0.0, atol=10.0 * dt)
    dt = 0.01
    INTEGRATORS["rk3"](ode, AnyStage(), 0.0, dt)
    from scipy.linalg import expm

    assert np.abs(ode.y - expm(ode.a * dt) @ y0).max() < 1e-7  # (third order: dt^4 |A|^4 / 24 = 7e-9)
