"""The equations of state of the weakly compressible fluid, written once for the kernels and the schemes.

    linear: p = c0^2 (rho - rho0)                                              (seed 001 eq. 1)
    tait:   p = B [(rho / rho0)^gamma - 1],  B = c0^2 rho0 / gamma,  gamma = 7  (thesis eq. 5.4, p0 = 0)

and their inverses and sound speeds c = sqrt(dp/drho): c0, and c0 (rho / rho0)^((gamma - 1) / 2). Each is a
numba ufunc of (value, c0, rho0, tait): elementwise over arrays from Python, a scalar call inside a kernel.
Out of range, Tait's density of p <= -B (the vacuum, rho = 0, where the pressure cannot fall lower) is 0, an
overflow inf, and NaN stays NaN (psph.schemes.eos silences numpy's warnings; the fluid driver's checks name
the particle).
tests/schemes/test_delta_ale.py checks the inverses and c^2 = dp/drho by central differences.
"""

from numba import vectorize

TAIT_GAMMA = 7.0  # Tait's exponent (thesis eq. 5.4)
SIGNATURE = ["float64(float64, float64, float64, boolean)"]


@vectorize(SIGNATURE, cache=True)
def pressure(rho, c0, rho0, tait):
    """p(rho)."""
    if tait:
        return c0 * c0 * rho0 / TAIT_GAMMA * ((rho / rho0) ** TAIT_GAMMA - 1.0)
    return c0 * c0 * (rho - rho0)


@vectorize(SIGNATURE, cache=True)
def density(p, c0, rho0, tait):
    """rho(p), the inverse of pressure; Tait's is 0 at and below p = -B (the vacuum)."""
    if tait:
        base = 1.0 + p * TAIT_GAMMA / (c0 * c0 * rho0)
        if base < 0.0:  # (NaN stays NaN)
            base = 0.0
        return rho0 * base ** (1.0 / TAIT_GAMMA)
    return rho0 + p / (c0 * c0)


@vectorize(SIGNATURE, cache=True)
def sound_speed(rho, c0, rho0, tait):
    """c = sqrt(dp/drho): c0 for the linear law, c0 (rho / rho0)^3 for Tait (1.33 c0 at 10% compression)."""
    if tait:
        return c0 * (rho / rho0) ** (0.5 * (TAIT_GAMMA - 1.0))
    return c0
