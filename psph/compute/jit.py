"""numba compilation of the kernels specialised per dimension."""

from numba import njit


def per_dimension(d):
    """njit(cache=True) for a kernel compiled once per dimension d: a closure over d, a compile-time constant, so
    that a 2-D kernel tests no d and computes no padded third component per pair.

    The kernel's name gets the dimension. numba names its on-disk cache after the function, so the closures of
    one function for d = 1, 2, 3 would otherwise share one cache index, and two processes compiling different
    dimensions at once (numba's index update takes no lock) could leave it pointing one dimension's entry at
    another's code."""

    def decorate(fn):
        fn.__qualname__ = f"{fn.__qualname__}_{d}d"
        return njit(cache=True)(fn)

    return decorate
