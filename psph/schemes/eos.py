"""The scene's equation of state (physics.eos): psph.compute.eos's formulas with the scene's c0 and rho0."""

import numpy as np

from psph.compute import eos as formulas


class EquationOfState:
    """p(rho), rho(p) and the sound speed of the linear law (seed 001 eq. 1) or Tait's (thesis eq. 5.4),
    elementwise over arrays (compiled: numpy warns of nothing). Out of range (an overflow, a NaN) they give inf
    or NaN: the fluid driver's check names the particle and the step."""

    def __init__(self, name, c0, rho0):  # name: "linear" or "tait" (the schema's choices)
        self.name, self.c0, self.rho0 = name, c0, rho0
        self.tait = name == "tait"

    def _apply(self, formula, values):
        out = formulas.elementwise(formula, np.asarray(values, dtype=np.float64), float(self.c0), float(self.rho0),
                                   self.tait)
        return out[()] if out.ndim == 0 else out  # (a number for a number, as numpy's ufuncs give)

    def pressure(self, rho):
        return self._apply(formulas.PRESSURE, rho)

    def density(self, p):
        return self._apply(formulas.DENSITY, p)

    def sound_speed(self, rho):
        return self._apply(formulas.SOUND_SPEED, rho)


def make_eos(physics) -> EquationOfState:
    return EquationOfState(physics.eos, physics.sound_speed, physics.density)
