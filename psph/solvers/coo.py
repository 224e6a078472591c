"""COO assembly of PETSc matrices: preallocate once from (row, col) pairs, then set all values at once.

petsc4py >= 3.19 binds MatSetPreallocationCOO / MatSetValuesCOO; Debian's petsc4py 3.18 does not,
although its PETSc library has them, so there they are called through ctypes on the matrix handle.
Repeated (row, col) pairs are summed by PETSc.
"""

import ctypes

import numpy as np

from psph.errors import PsphError
from psph.solvers.petsc import petsc

_lib = {}


def _petsc_library():
    """The libpetsc shared object petsc4py loaded (found in this process's memory map)."""
    if "lib" not in _lib:
        petsc()
        paths = sorted({line.split()[-1] for line in open("/proc/self/maps") if "libpetsc" in line})
        if not paths:
            raise PsphError("cannot find the PETSc library for COO assembly (upgrade petsc4py to >= 3.19)")
        lib = ctypes.CDLL(paths[0])
        lib.MatSetPreallocationCOO.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p]
        lib.MatSetPreallocationCOO.restype = ctypes.c_int
        lib.MatSetValuesCOO.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int]
        lib.MatSetValuesCOO.restype = ctypes.c_int
        _lib["lib"] = lib
    return _lib["lib"]


def _check(code, what):
    if code != 0:
        raise PsphError(f"PETSc error {code} in {what}")


class COOAssembly:
    """A matrix whose nonzero pattern is fixed by COO pairs and whose values are replaced at once."""

    def __init__(self, mat, rows: np.ndarray, cols: np.ndarray):
        PETSc = petsc()
        self.mat = mat
        self.native = hasattr(mat, "setPreallocationCOO")
        rows = np.ascontiguousarray(rows, dtype=PETSc.IntType)
        cols = np.ascontiguousarray(cols, dtype=PETSc.IntType)
        self.nnz = len(rows)
        if self.native:
            mat.setPreallocationCOO(rows, cols)
        else:
            _check(_petsc_library().MatSetPreallocationCOO(mat.handle, len(rows), rows.ctypes.data,
                                                           cols.ctypes.data), "MatSetPreallocationCOO")

    def set_values(self, values: np.ndarray) -> None:
        """Replace the matrix values (one per COO pair, in the preallocation order); assembles."""
        values = np.ascontiguousarray(values, dtype=np.float64)
        if len(values) != self.nnz:
            raise ValueError(f"{len(values)} COO values for {self.nnz} pairs")
        if self.native:
            self.mat.setValuesCOO(values, petsc().InsertMode.INSERT_VALUES)
        else:
            _check(_petsc_library().MatSetValuesCOO(self.mat.handle, values.ctypes.data,
                                                    int(petsc().InsertMode.INSERT_VALUES)), "MatSetValuesCOO")
