"""Distributed AIJ matrices with a fixed pattern: built once per neighbour-list rebuild, values rewritten in place.

An AIJ matrix (the default) is built on the pattern arrays themselves, without copying or inserting:
MatCreateSeqAIJWithArrays on one rank, MatCreateMPIAIJWithSplitArrays (diagonal block with local
columns, off-diagonal block with global ones) on several (~2 ms for 1.6M nonzeros, where
`setPreallocationCSR`, which inserts entry by entry, takes 60-90 ms). Values then go straight into
PETSc's value arrays of the local diagonal and off-diagonal SeqAIJ blocks, reached through PETSc's public
C API (MatMPIAIJGetSeqAIJ, MatGetRowIJ, MatSeqAIJGetArray/RestoreArray) with ctypes, because petsc4py
3.18 binds none of them. Another matrix type asked for on the command line (e.g. -iips_mat_type baij) is
preallocated with `setPreallocationCSR` and filled through the generic `setValuesCSR` path. Either way
the matrix is re-assembled, which advances its state so that preconditioners are set up again.
"""

import ctypes

import numpy as np

from psph.compute.csr import block_major_positions, scatter, split_csr, split_positions, write_split
from psph.errors import PsphError
from psph.parallel.comm import exclusive_scan
from psph.solvers.petsc import petsc

_lib = {}
_ptr = ctypes.c_void_p


def _petsc_library():
    """The libpetsc shared object petsc4py loaded (found in this process's memory map)."""
    if "lib" not in _lib:
        petsc()
        paths = sorted({line.split()[-1] for line in open("/proc/self/maps") if "libpetsc" in line})
        if not paths:
            raise PsphError("cannot locate the PETSc library loaded by petsc4py")
        lib = ctypes.CDLL(paths[0])
        for name, args in (("MatSeqAIJGetArray", [_ptr, ctypes.POINTER(_ptr)]),
                           ("MatSeqAIJRestoreArray", [_ptr, ctypes.POINTER(_ptr)]),
                           ("MatMPIAIJGetSeqAIJ", [_ptr, ctypes.POINTER(_ptr), ctypes.POINTER(_ptr),
                                                   ctypes.POINTER(_ptr)]),
                           ("MatGetRowIJ", [_ptr, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                                            ctypes.POINTER(ctypes.c_int), ctypes.POINTER(_ptr),
                                            ctypes.POINTER(_ptr), ctypes.POINTER(ctypes.c_int)]),
                           ("MatRestoreRowIJ", [_ptr, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                                                ctypes.POINTER(ctypes.c_int), ctypes.POINTER(_ptr),
                                                ctypes.POINTER(_ptr), ctypes.POINTER(ctypes.c_int)]),
                           ("MatCreateMPIAIJWithSplitArrays", [_ptr] + [_int_type()] * 4 + [_ptr] * 6
                            + [ctypes.POINTER(_ptr)]),
                           ("PCSetOperators", [_ptr, _ptr, _ptr]),
                           ("MatDestroy", [ctypes.POINTER(_ptr)])):
            fn = getattr(lib, name)
            fn.argtypes = args
            fn.restype = ctypes.c_int
        _lib["lib"] = lib
    return _lib["lib"]


def _int_type():
    return ctypes.c_int32 if np.dtype(petsc().IntType).itemsize == 4 else ctypes.c_int64


def _check(code, what):
    if code != 0:
        raise PsphError(f"PETSc error {code} in {what}")


class _Memory:
    """An array interface over foreign memory: numpy views it without a new ctypes type per size (the types
    np.ctypeslib.as_array makes are cached for good, a leak when the size changes at every rebuild)."""

    def __init__(self, address, size, typestr):
        self.__array_interface__ = {"data": (address, False), "shape": (size,), "typestr": typestr, "version": 3}


def _doubles_at(address, size):
    return np.asarray(_Memory(address, size, "<f8"))


def _row_pointers(lib, handle):
    """Row pointers (ia) of a SeqAIJ matrix, as int64."""
    n = ctypes.c_int()
    ia, ja = _ptr(), _ptr()
    done = ctypes.c_int()
    _check(lib.MatGetRowIJ(handle, 0, 0, 0, ctypes.byref(n), ctypes.byref(ia), ctypes.byref(ja),
                           ctypes.byref(done)), "MatGetRowIJ")
    if not done.value:
        raise PsphError("MatGetRowIJ is not supported for this matrix")
    int_type = _int_type()
    if n.value == 0 or not ia.value:  # a rank without rows: PETSc need not give a row-pointer array
        rows = np.zeros(1, dtype=np.int64)
    else:
        rows = np.asarray(_Memory(ia.value, n.value + 1, np.dtype(int_type).str)).astype(np.int64)
    _check(lib.MatRestoreRowIJ(handle, 0, 0, 0, ctypes.byref(n), ctypes.byref(ia), ctypes.byref(ja),
                               ctypes.byref(done)), "MatRestoreRowIJ")
    return rows


def _aij_on_arrays(comm, indptr, indices, n_global):
    """An AIJ matrix whose storage is the given pattern (values zero), without insertion. Returns the
    petsc4py Mat and the arrays PETSc now uses (keep them alive as long as the matrix). Collective."""
    PETSc = petsc()
    n_local = len(indptr) - 1
    if comm.size == 1:
        arrays = (np.asarray(indptr, dtype=PETSc.IntType), np.asarray(indices, dtype=PETSc.IntType),
                  np.zeros(len(indices)))
        return PETSc.Mat().createAIJWithArrays((n_local, n_local), arrays, comm=comm), arrays
    from mpi4py import MPI

    start = exclusive_scan(comm, n_local)
    di, dj, oi, oj = split_csr(np.asarray(indptr, np.int64), np.asarray(indices, np.int64), start, start + n_local)
    arrays = tuple(np.ascontiguousarray(a, dtype=PETSc.IntType) for a in (di, dj, oi, oj))
    arrays += (np.zeros(len(dj)), np.zeros(len(oj)))
    di, dj, oi, oj, da, oa = arrays
    lib = _petsc_library()
    handle = _ptr()
    _check(lib.MatCreateMPIAIJWithSplitArrays(_ptr(MPI._handleof(comm)), n_local, n_local, n_global, n_global,
                                              di.ctypes.data, dj.ctypes.data, da.ctypes.data, oi.ctypes.data,
                                              oj.ctypes.data, oa.ctypes.data, ctypes.byref(handle)),
           "MatCreateMPIAIJWithSplitArrays")
    # petsc4py 3.18 cannot wrap a C handle directly; a PC hands back the operator it was given as a Mat
    pc = PETSc.PC().create(comm=comm)
    _check(lib.PCSetOperators(_ptr(pc.handle), handle, handle), "PCSetOperators")
    mat, _ = pc.getOperators()
    pc.destroy()
    _check(lib.MatDestroy(ctypes.byref(handle)), "MatDestroy")  # the Mat wrapper holds its own reference
    return mat, arrays


class FixedPatternMatrix:
    """A square distributed matrix with block size `bsize`, pattern (indptr, indices) and `slot`, the
    CSR position of every value a value kernel produces (repeats add up). Collective constructor."""

    def __init__(self, comm, indptr, indices, slot, n_global, bsize, prefix):
        PETSc = petsc()
        n_local = len(indptr) - 1
        self.arrays = ()
        if PETSc.Options().getString(f"{prefix}mat_type", "aij") in ("aij", "seqaij", "mpiaij"):
            mat, self.arrays = _aij_on_arrays(comm, indptr, indices, n_global)
            mat.setBlockSize(bsize)
            mat.setOptionsPrefix(prefix)
        else:
            mat = PETSc.Mat().create(comm=comm)
            mat.setSizes(((n_local, n_global), (n_local, n_global)), bsize=bsize)
            mat.setOptionsPrefix(prefix)
            mat.setFromOptions()
        self.kind = mat.getType()
        self.blocked = bsize > 1 and "baij" in self.kind
        if self.blocked:  # block CSR: the scalar layout per particle row is already row-oriented blocks
            d2 = bsize * bsize
            self.indptr = np.asarray(np.asarray(indptr)[::bsize] // d2, dtype=PETSc.IntType)
            first = np.concatenate([np.arange(indptr[r], indptr[r + 1], bsize) for r in range(0, n_local, bsize)])
            self.indices = np.asarray(np.asarray(indices)[first.astype(np.int64)] // bsize, dtype=PETSc.IntType)
            slot = block_major_positions(np.asarray(indptr, np.int64), bsize)[slot]
        else:
            self.indptr = np.asarray(indptr, dtype=PETSc.IntType)
            self.indices = np.asarray(indices, dtype=PETSc.IntType)
        if not self.arrays:
            mat.setPreallocationCSR((self.indptr, self.indices))
        mat.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        self.mat = mat
        self.slot = slot
        self.target = np.zeros(len(slot), dtype=np.int8)  # 0: diagonal block, 1: off-diagonal block
        self.offset = np.asarray(slot, dtype=np.int64)  # position in that block's values
        self.blocks = []  # (SeqAIJ handle, number of values) of the blocks written in place
        if self.kind == "seqaij":
            self.blocks = [(mat.handle, len(indices))]
        elif self.kind == "mpiaij":
            lib = _petsc_library()
            ad, ao, colmap = _ptr(), _ptr(), _ptr()
            _check(lib.MatMPIAIJGetSeqAIJ(mat.handle, ctypes.byref(ad), ctypes.byref(ao), ctypes.byref(colmap)),
                   "MatMPIAIJGetSeqAIJ")
            start, end = mat.getOwnershipRangeColumn()
            ia_d, ia_o = _row_pointers(lib, ad), _row_pointers(lib, ao)
            self.offset = np.empty(len(slot), dtype=np.int64)
            if split_positions(np.asarray(indptr, np.int64), np.asarray(indices, np.int64), start, end, ia_d, ia_o,
                                np.asarray(slot, np.int64), self.target, self.offset):
                self.blocks = [(ad.value, int(ia_d[-1])), (ao.value, int(ia_o[-1]))]
        self.values = None if self.blocks else np.zeros(len(indices))

    def destroy(self) -> None:
        """Free the PETSc matrix now. Dropping the last Python reference is not enough: petsc4py 3.18 keeps a
        matrix made on our arrays, and the arrays, alive (12 MB per 10^6 nonzeros on every neighbour-list
        rebuild: a Taylor-Green IIPS run at dx = 0.0125 reached 13 GB). Collective."""
        self.mat.destroy()
        self.blocks = []

    def set_values(self, natural):
        """Replace the matrix values by `natural` (one per slot, repeats summed) and assemble. Collective."""
        if not self.blocks:  # generic path (other matrix types)
            scatter(natural, self.slot, self.values)
            if self.blocked:
                self.mat.setValuesBlockedCSR(self.indptr, self.indices, self.values)
            else:
                self.mat.setValuesCSR(self.indptr, self.indices, self.values)
        else:
            lib = _petsc_library()
            pointers, views = [], []
            for handle, size in self.blocks:
                data = _ptr()
                _check(lib.MatSeqAIJGetArray(handle, ctypes.byref(data)), "MatSeqAIJGetArray")
                pointers.append((handle, data))
                views.append(_doubles_at(data.value, size) if size else np.zeros(0))
            if len(views) == 1:
                views.append(np.zeros(0))
            write_split(natural, self.target, self.offset, views[0], views[1])
            for handle, data in pointers:
                _check(lib.MatSeqAIJRestoreArray(handle, ctypes.byref(data)), "MatSeqAIJRestoreArray")
        self.mat.assemble()
