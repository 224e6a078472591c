"""The equations of state of the weakly compressible fluid, written once for the kernels and the schemes.

    linear: p = c0^2 (rho - rho0)                                              (seed 001 eq. 1)
    tait:   p = B [(rho / rho0)^gamma - 1],  B = c0^2 rho0 / gamma,  gamma = 7  (thesis eq. 5.4, p0 = 0)

and their inverses and sound speeds c = sqrt(dp/drho): c0, and c0 (rho / rho0)^((gamma - 1) / 2). Each is a
scalar numba function of (value, c0, rho0, tait), which the kernels call; `elementwise` applies one over an
array (psph.schemes.eos). (Numba ufuncs did the same, but numba rebuilt them in every process, cache or not:
0.35-0.5 s of each run's start, a speed audit measured.)
Out of range, Tait's density of p <= -B (the vacuum, rho = 0, where the pressure cannot fall lower) is 0, an
overflow inf, and NaN stays NaN (compiled, they warn of nothing; the fluid driver's checks name the
particle).
tests/schemes/test_delta_ale.py checks the inverses and c^2 = dp/drho by central differences.
"""

import numpy as np
from numba import njit

TAIT_GAMMA = 7.0  # Tait's exponent (thesis eq. 5.4)


@njit(cache=True)
def pressure(rho, c0, rho0, tait):
    """p(rho)."""
    if tait:
        return c0 * c0 * rho0 / TAIT_GAMMA * ((rho / rho0) ** TAIT_GAMMA - 1.0)
    return c0 * c0 * (rho - rho0)


@njit(cache=True)
def density(p, c0, rho0, tait):
    """rho(p), the inverse of pressure; Tait's is 0 at and below p = -B (the vacuum)."""
    if tait:
        base = 1.0 + p * TAIT_GAMMA / (c0 * c0 * rho0)
        if base < 0.0:  # (NaN stays NaN)
            base = 0.0
        return rho0 * base ** (1.0 / TAIT_GAMMA)
    return rho0 + p / (c0 * c0)


@njit(cache=True)
def sound_speed(rho, c0, rho0, tait):
    """c = sqrt(dp/drho): c0 for the linear law, c0 (rho / rho0)^3 for Tait (1.33 c0 at 10% compression)."""
    if tait:
        return c0 * (rho / rho0) ** (0.5 * (TAIT_GAMMA - 1.0))
    return c0


PRESSURE, DENSITY, SOUND_SPEED = 0, 1, 2  # elementwise's formulas


@njit(cache=True)
def elementwise(formula, values, c0, rho0, tait):
    """PRESSURE, DENSITY or SOUND_SPEED of each entry of the float64 array `values` (a new array, its shape)."""
    flat = values.ravel()
    out = np.empty(flat.size)
    for i in range(flat.size):
        if formula == PRESSURE:
            out[i] = pressure(flat[i], c0, rho0, tait)
        elif formula == DENSITY:
            out[i] = density(flat[i], c0, rho0, tait)
        else:
            out[i] = sound_speed(flat[i], c0, rho0, tait)
    return out.reshape(values.shape)
