"""Equations of state of the weakly compressible fluid.

linear: p = c0^2 (rho - rho0)                                  (seed 001 eq. 1)
tait:   p = c0^2 rho0 / gamma [(rho / rho0)^gamma - 1],  gamma = 7  (thesis eq. 5.4, p0 = 0)

Out of range (Tait's density of p < -B, an overflow) they give NaN or inf without numpy's warning: the fluid
driver's check names the particle and the step.
"""

import functools

import numpy as np

from psph.compute.riemann import TAIT_GAMMA

GAMMA = TAIT_GAMMA


def quiet(method):
    """`method` without numpy's floating-point warnings (a fresh errstate per call: a shared one is not
    re-entrant)."""
    @functools.wraps(method)
    def call(*args):
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return method(*args)
    return call


class LinearEOS:
    name = "linear"

    def __init__(self, c0, rho0):
        self.c0, self.rho0 = c0, rho0

    @quiet
    def pressure(self, rho):
        return self.c0 ** 2 * (rho - self.rho0)

    @quiet
    def density(self, p):
        return self.rho0 + p / self.c0 ** 2

    def sound_speed(self, rho):
        """c = sqrt(dp/drho) = c0 at any density."""
        return np.full_like(np.asarray(rho, dtype=np.float64), self.c0)


class TaitEOS:
    name = "tait"

    def __init__(self, c0, rho0):
        self.c0, self.rho0 = c0, rho0
        self.b = c0 ** 2 * rho0 / GAMMA

    @quiet
    def pressure(self, rho):
        return self.b * ((rho / self.rho0) ** GAMMA - 1.0)

    @quiet
    def density(self, p):
        return self.rho0 * (1.0 + np.asarray(p) / self.b) ** (1.0 / GAMMA)

    @quiet
    def sound_speed(self, rho):
        """c = sqrt(dp/drho) = c0 (rho / rho0)^((gamma - 1) / 2): 1.33 c0 at 10% compression."""
        return self.c0 * (np.asarray(rho) / self.rho0) ** (0.5 * (GAMMA - 1.0))


def make_eos(physics):
    cls = {"linear": LinearEOS, "tait": TaitEOS}[physics.eos]
    return cls(physics.sound_speed, physics.density)
