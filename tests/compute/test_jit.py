"""Kernels compiled per dimension (compute.jit.per_dimension) each keep their own numba cache index."""

from psph.compute import fluid, iips, riemann, shift_velocity, sums


def test_every_dimension_has_its_own_cache_index():
    """Two processes compiling one kernel for different dimensions at once must not update the same index."""
    tables = {"sums.GRAD_CONCENTRATION": sums.GRAD_CONCENTRATION, "iips.MATRIX_FREE": iips.MATRIX_FREE,
              "fluid._KERNELS": fluid._KERNELS, "riemann._KERNELS": riemann._KERNELS,
              "shift_velocity._GRAD_C": shift_velocity._GRAD_C, "shift_velocity._NEUHAUSER": shift_velocity._NEUHAUSER}
    indexes = []
    for name, table in tables.items():
        assert sorted(table) == [1, 2, 3], name
        for kernels in table.values():
            for kernel in kernels if isinstance(kernels, tuple) else (kernels,):
                indexes.append(kernel._cache._cache_file._index_path)
    assert len(set(indexes)) == len(indexes) == 3 * 9
