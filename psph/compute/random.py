"""Counter-based pseudo-random numbers keyed by (seed, particle gid) (numba).

Each particle's numbers depend only on the seed and its global id, so an initial perturbation is the same
whatever the number of ranks and however particles are distributed. The generator is splitmix64
(Steele, Lea, Flood 2014) applied to a per-(seed, gid, draw) counter; normals by Box-Muller.
"""

import numpy as np
from numba import njit, uint64

_GOLDEN = uint64(0x9E3779B97F4A7C15)
_M1 = uint64(0xBF58476D1CE4E5B9)
_M2 = uint64(0x94D049BB133111EB)


@njit(cache=True)
def _splitmix64(x):
    z = x + _GOLDEN
    z = (z ^ (z >> uint64(30))) * _M1
    z = (z ^ (z >> uint64(27))) * _M2
    return z ^ (z >> uint64(31))


@njit(cache=True)
def _uniform(seed, gid, draw):
    """U(0, 1], 53 random bits."""
    key = _splitmix64(uint64(seed)) ^ _splitmix64(uint64(gid) * uint64(64) + uint64(draw))
    bits = _splitmix64(key) >> uint64(11)
    return (float(bits) + 1.0) * (1.0 / 9007199254740992.0)


@njit(cache=True)
def gaussian_by_gid(seed, gid, dim):
    """(n, dim) standard normal numbers; row k depends only on (seed, gid[k])."""
    n = gid.size
    out = np.empty((n, dim))
    for i in range(n):
        for a in range(0, dim, 2):
            u1 = _uniform(seed, gid[i], 2 * a)
            u2 = _uniform(seed, gid[i], 2 * a + 1)
            rad = np.sqrt(-2.0 * np.log(u1))
            out[i, a] = rad * np.cos(2.0 * np.pi * u2)
            if a + 1 < dim:
                out[i, a + 1] = rad * np.sin(2.0 * np.pi * u2)
    return out
