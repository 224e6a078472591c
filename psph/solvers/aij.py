"""Distributed AIJ / BAIJ matrices with a fixed pattern: built once per neighbour-list rebuild, values
rewritten in place.

An AIJ matrix is built on the pattern arrays themselves, without copying or inserting:
MatCreateSeqAIJWithArrays on one rank, MatCreateMPIAIJWithSplitArrays (diagonal block with local
columns, off-diagonal block with global ones) on several (~2 ms for 1.6M nonzeros, where
`setPreallocationCSR`, which inserts entry by entry, takes 60-90 ms). A BAIJ matrix (block size d) is
preallocated from its block pattern (PETSc 3.18 has no BAIJ on given arrays for block sizes above 1).
Values then go straight into PETSc's value arrays of the local diagonal and off-diagonal SeqAIJ /
SeqBAIJ blocks, reached through PETSc's public C API (MatMPI(B)AIJGetSeq(B)AIJ, MatGetRowIJ,
MatSeq(B)AIJGetArray/RestoreArray) with ctypes, because petsc4py 3.18 binds none of them. Another matrix
type asked for on the command line (e.g. -iips_mat_type sell) is preallocated with `setPreallocationCSR`
and filled through the generic `setValuesCSR` path. Either way the matrix is re-assembled, which
advances its state so that preconditioners are set up again.
"""

import ctypes

import numpy as np

from psph.compute.csr import block_codes, block_pattern, split_csr, split_positions
from psph.errors import PsphError
from psph.parallel.comm import allreduce_sum, exclusive_scan
from psph.solvers.petsc import petsc, petsc_comm

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
                           ("MatSeqBAIJGetArray", [_ptr, ctypes.POINTER(_ptr)]),
                           ("MatSeqBAIJRestoreArray", [_ptr, ctypes.POINTER(_ptr)]),
                           ("MatMPIBAIJGetSeqBAIJ", [_ptr, ctypes.POINTER(_ptr), ctypes.POINTER(_ptr),
                                                     ctypes.POINTER(_ptr)]),
                           ("MatSeqBAIJSetColumnIndices", [_ptr, _ptr]),
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


def _row_pointers(lib, handle, blocks=False):
    """Row pointers (ia) of a SeqAIJ matrix, or block-row pointers of a SeqBAIJ one (blocks), as int64."""
    n = ctypes.c_int()
    ia, ja = _ptr(), _ptr()
    done = ctypes.c_int()
    _check(lib.MatGetRowIJ(handle, 0, 0, int(blocks), ctypes.byref(n), ctypes.byref(ia), ctypes.byref(ja),
                           ctypes.byref(done)), "MatGetRowIJ")
    if not done.value:
        raise PsphError("MatGetRowIJ is not supported for this matrix")
    int_type = _int_type()
    if n.value == 0 or not ia.value:  # a rank without rows: PETSc need not give a row-pointer array
        rows = np.zeros(1, dtype=np.int64)
    else:
        rows = np.asarray(_Memory(ia.value, n.value + 1, np.dtype(int_type).str)).astype(np.int64)
    _check(lib.MatRestoreRowIJ(handle, 0, 0, int(blocks), ctypes.byref(n), ctypes.byref(ia), ctypes.byref(ja),
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
        return PETSc.Mat().createAIJWithArrays((n_local, n_local), arrays, comm=petsc_comm(comm)), arrays
    from mpi4py import MPI

    start = exclusive_scan(comm, n_local)
    di, dj, oi, oj = split_csr(indptr, indices, start, start + n_local)
    arrays = tuple(np.ascontiguousarray(a, dtype=PETSc.IntType) for a in (di, dj, oi, oj))
    arrays += (np.zeros(len(dj)), np.zeros(len(oj)))
    di, dj, oi, oj, da, oa = arrays
    lib = _petsc_library()
    handle, mpi_comm = _ptr(), _ptr(MPI._handleof(petsc_comm(comm)))
    _check(lib.MatCreateMPIAIJWithSplitArrays(mpi_comm, n_local, n_local, n_global, n_global,
                                              di.ctypes.data, dj.ctypes.data, da.ctypes.data, oi.ctypes.data,
                                              oj.ctypes.data, oa.ctypes.data, ctypes.byref(handle)),
           "MatCreateMPIAIJWithSplitArrays")
    return _wrap(comm, handle), arrays


def _baij(comm, bptr, bcols, bsize, n_global):
    """A BAIJ matrix of block size `bsize` on the block pattern (bptr, bcols; global block columns), values
    zero. PETSc 3.18 builds no BAIJ on given arrays for block sizes above 1. One rank: exact preallocation,
    then the column indices copied in (MatSeqBAIJSetColumnIndices: 0.5 ms where the CSR preallocation,
    which inserts block by block, takes 9 ms at 6400 particles); several: the CSR preallocation. Collective."""
    PETSc = petsc()
    n_local = (len(bptr) - 1) * bsize
    sizes = ((n_local, n_global), (n_local, n_global))
    bptr, bcols = (np.asarray(a, dtype=PETSc.IntType) for a in (bptr, bcols))
    if comm.size > 1:
        return PETSc.Mat().createBAIJ(sizes, bsize, csr=(bptr, bcols), comm=petsc_comm(comm))
    mat = PETSc.Mat().createBAIJ(sizes, bsize, nnz=np.diff(bptr), comm=petsc_comm(comm))
    _check(_petsc_library().MatSeqBAIJSetColumnIndices(mat.handle, bcols.ctypes.data), "MatSeqBAIJSetColumnIndices")
    mat.assemble()
    return mat


def _wrap(comm, handle):
    """A petsc4py Mat for a new C Mat handle, whose own reference is then dropped. petsc4py 3.18 cannot wrap
    a C handle directly; a PC hands back the operator it was given as a Mat."""
    PETSc = petsc()
    lib = _petsc_library()
    pc = PETSc.PC().create(comm=petsc_comm(comm))
    _check(lib.PCSetOperators(_ptr(pc.handle), handle, handle), "PCSetOperators")
    mat, _ = pc.getOperators()
    pc.destroy()
    _check(lib.MatDestroy(ctypes.byref(handle)), "MatDestroy")  # the Mat wrapper holds its own reference
    return mat


class FixedPatternMatrix:
    """A square distributed matrix with block size `bsize`, pattern (indptr, indices) and `slot`, the
    CSR position of every value a value kernel produces (repeats add up). Collective constructor.

    The kernel writes into the matrix's storage itself (set_values): `where` codes each value's position,
    p >= 0 in the local diagonal block's values (on one rank: all values), -1 - p in the off-diagonal
    block's (csr.add_at), as int32 like the pattern (compute.iips.iips_structure checks that it fits).
    AIJ (the default) and BAIJ (`-<prefix>mat_type baij`, block size d: a quarter of AIJ's column indices,
    fewer bytes per matrix-vector product) are written in place; other types go through setValuesCSR."""

    ACCESS = {"aij": ("MatSeqAIJGetArray", "MatSeqAIJRestoreArray", "MatMPIAIJGetSeqAIJ"),
              "baij": ("MatSeqBAIJGetArray", "MatSeqBAIJRestoreArray", "MatMPIBAIJGetSeqBAIJ")}

    def __init__(self, comm, indptr, indices, slot, n_global, bsize, prefix):
        PETSc = petsc()
        n_local = len(indptr) - 1
        self.arrays = ()
        family = family_of(prefix)
        if family == "baij" and bsize == 1:  # blocks of one value: AIJ in all but name (1-D)
            family = "aij"
        if family == "baij":
            bptr, bcols = block_pattern(indptr, indices, bsize)
            mat = _baij(comm, bptr, bcols, bsize, n_global)
        elif family == "aij":
            mat, self.arrays = _aij_on_arrays(comm, indptr, indices, n_global)
            mat.setBlockSize(bsize)
        else:
            mat = PETSc.Mat().create(comm=petsc_comm(comm))
            mat.setSizes(((n_local, n_global), (n_local, n_global)), bsize=bsize)
        mat.setOptionsPrefix(prefix)
        if family is None:
            mat.setFromOptions()
        self.kind = mat.getType()
        self.blocked = bsize > 1 and "baij" in self.kind
        self.mat = mat
        self.blocks = []  # (SeqAIJ / SeqBAIJ handle, number of values) of the blocks written in place
        self.where = None
        if self.kind in ("seqaij", "seqbaij"):
            size = len(indices) if self.kind == "seqaij" else len(bcols) * bsize * bsize
            self.blocks = [(mat.handle, size)]
            self.where = np.asarray(slot, dtype=np.int32)
            if self.blocked:
                block_codes(indptr, bsize, bptr, np.arange(len(bcols), dtype=np.int32), slot, self.where)
        elif self.kind in ("mpiaij", "mpibaij"):
            self._split(indptr, indices, slot, bsize, *((bptr, bcols) if self.blocked else (None, None)))
        if not self.blocks:  # generic path (other matrix types): CSR values, then setValues(Blocked)CSR
            self._generic(indptr, indices, slot, bsize, preallocate=family is None)
        if family is not None:  # the pattern is exactly the one built
            mat.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)

    def _split(self, indptr, indices, slot, bsize, bptr, bcols):
        """Codes into the diagonal and off-diagonal blocks of an MPIAIJ / MPIBAIJ matrix (if their patterns
        are the ones expected; otherwise the generic path is used)."""
        lib = _petsc_library()
        ad, ao, colmap = _ptr(), _ptr(), _ptr()
        get_blocks = getattr(lib, self.ACCESS["baij" if self.blocked else "aij"][2])
        _check(get_blocks(self.mat.handle, ctypes.byref(ad), ctypes.byref(ao), ctypes.byref(colmap)),
               "MatMPI(B)AIJGetSeq(B)AIJ")
        start, end = self.mat.getOwnershipRangeColumn()
        ia_d, ia_o = _row_pointers(lib, ad, self.blocked), _row_pointers(lib, ao, self.blocked)
        where = np.empty(len(slot), dtype=np.int32)
        if self.blocked:
            block_where = np.empty(len(bcols), dtype=np.int32)
            ok = split_positions(bptr, bcols, start // bsize, end // bsize, ia_d, ia_o,
                                 np.arange(len(bcols), dtype=np.int32), block_where)
            if ok:
                block_codes(indptr, bsize, bptr, block_where, slot, where)
            per_block = bsize * bsize
        else:
            ok = split_positions(indptr, indices, start, end, ia_d, ia_o, slot, where)
            per_block = 1
        if ok:
            self.blocks = [(ad.value, int(ia_d[-1]) * per_block), (ao.value, int(ia_o[-1]) * per_block)]
            self.where = where

    def _generic(self, indptr, indices, slot, bsize, preallocate):
        PETSc = petsc()
        if self.blocked:  # block CSR values, blocks column-major as block_codes writes them
            pattern = block_pattern(indptr, indices, bsize)
            self.indptr, self.indices = (np.asarray(a, dtype=PETSc.IntType) for a in pattern)
            self.where = np.empty(len(slot), dtype=np.int32)
            block_codes(indptr, bsize, pattern[0], np.arange(len(pattern[1]), dtype=np.int32), slot, self.where)
            self.mat.setOption(PETSc.Mat.Option.ROW_ORIENTED, False)
        else:
            self.indptr = np.asarray(indptr, dtype=PETSc.IntType)
            self.indices = np.asarray(indices, dtype=PETSc.IntType)
            self.where = np.asarray(slot, dtype=np.int32)
        if preallocate:  # a type the CSR preallocation does not reach (e.g. sell) is set up by default
            self.mat.setPreallocationCSR((self.indptr, self.indices))
            self.mat.setUp()
        self.values = np.zeros(len(indices))

    def destroy(self) -> None:
        """Free the PETSc matrix now. Dropping the last Python reference is not enough: petsc4py 3.18 keeps a
        matrix made on our arrays, and the arrays, alive (12 MB per 10^6 nonzeros on every neighbour-list
        rebuild: a Taylor-Green IIPS run at dx = 0.0125 reached 13 GB). Collective."""
        self.mat.destroy()
        self.blocks = []

    def set_values(self, fill):
        """Replace the matrix values and assemble. fill(where, diag, off) zeroes diag and off and adds every
        value into its storage by its code in `where` (csr.add_at; e.g. compute.iips.iips_values). Collective."""
        if not self.blocks:  # generic path (other matrix types)
            fill(self.where, self.values, np.zeros(0))
            if self.blocked:
                self.mat.setValuesBlockedCSR(self.indptr, self.indices, self.values)
            else:
                self.mat.setValuesCSR(self.indptr, self.indices, self.values)
        else:
            lib = _petsc_library()
            get_name, restore_name, _ = self.ACCESS["baij" if self.blocked else "aij"]
            get, restore = getattr(lib, get_name), getattr(lib, restore_name)
            pointers, views = [], []
            for handle, size in self.blocks:
                data = _ptr()
                _check(get(handle, ctypes.byref(data)), get_name)
                pointers.append((handle, data))
                views.append(_doubles_at(data.value, size) if size else np.zeros(0))
            if len(views) == 1:
                views.append(np.zeros(0))
            try:
                fill(self.where, views[0], views[1])
            finally:
                for handle, data in pointers:
                    _check(restore(handle, ctypes.byref(data)), restore_name)
        self.mat.assemble()


def family_of(prefix) -> str:
    """"aij" or "baij", the matrix families FixedPatternMatrix writes in place, for `-<prefix>mat_type`
    (aij when not given); None for another type."""
    requested = petsc().Options().getString(f"{prefix}mat_type", "aij")
    return {"aij": "aij", "seqaij": "aij", "mpiaij": "aij", "baij": "baij", "seqbaij": "baij",
            "mpibaij": "baij"}.get(requested)


# matrix types that cannot hold the IIPS operator: SBAIJ stores the upper triangle only, and A = H diag(V) is
# not symmetric where the volumes differ (1 rank: another system solved, Taylor-Green's error 0.0348 against
# 0.0440; 2 and 3 ranks: a segmentation fault), and IS takes no values by CSR (a segmentation fault on 2 ranks;
# a PETSc-options audit)
REFUSED_MAT_TYPES = {"sbaij": "stores the upper triangle only, and the IIPS operator A = H diag(V) is not "
                              "symmetric where the volumes differ",
                     "is": "takes no values the way psph writes them"}


def check_mat_type(comm, prefix) -> None:
    """Refuse a `-<prefix>mat_type` of REFUSED_MAT_TYPES (UsageError), and raise PETSc's error now if it names
    no matrix type PETSc has: a type outside family_of's would otherwise fail at the first IIPS call, after
    the run has written its output. Collective."""
    from psph.errors import UsageError

    requested = petsc().Options().getString(f"{prefix}mat_type", "aij")
    for name, why in REFUSED_MAT_TYPES.items():
        if requested.lower() in (name, f"seq{name}", f"mpi{name}"):
            raise UsageError(f"-{prefix}mat_type {requested}: {name.upper()} {why}; use aij (the default), "
                             "baij, sell or dense")
    PETSc = petsc()
    mat = PETSc.Mat().create(comm=petsc_comm(comm))
    try:
        mat.setSizes(((1, comm.size), (1, comm.size)))
        mat.setOptionsPrefix(prefix)
        mat.setFromOptions()
    finally:
        mat.destroy()


def chain_matrix(comm, rows_per_rank, bsize, prefix) -> FixedPatternMatrix:
    """A small well-posed test matrix: `rows_per_rank` block rows on every rank, each coupled to the block
    rows before and after it (a chain over the ranks), diagonal blocks 4 I and off-diagonal blocks -I
    (symmetric, strictly diagonally dominant), of the type `-<prefix>mat_type` gives (aij by default).
    Collective."""
    first = int(exclusive_scan(comm, rows_per_rank))
    n_blocks = int(allreduce_sum(comm, rows_per_rank))
    # entries in row order: block row g, its row a, then block column s (g - 1, g, g + 1 where they exist), then
    # its column b
    g = np.arange(first, first + rows_per_rank)[:, None, None, None]
    s = g + np.array([-1, 0, 1])[None, None, :, None]
    a = np.arange(bsize)[None, :, None, None]
    b = np.arange(bsize)[None, None, None, :]
    shape = (rows_per_rank, bsize, 3, bsize)
    keep = np.broadcast_to((s >= 0) & (s < n_blocks), shape)
    indices = np.broadcast_to(s * bsize + b, shape)[keep]
    values = np.broadcast_to(np.where(a == b, np.where(s == g, 4.0, -1.0), 0.0), shape)[keep]
    indptr = np.concatenate([[0], np.cumsum(keep.sum(axis=(2, 3)).ravel())])
    matrix = FixedPatternMatrix(comm, indptr, indices, np.arange(len(values)), n_blocks * bsize, bsize, prefix)

    def fill(where, diag, off):
        diag[:] = 0.0
        off[:] = 0.0
        local = where >= 0
        np.add.at(diag, where[local], values[local])
        np.add.at(off, -1 - where[~local], values[~local])

    matrix.set_values(fill)
    return matrix
