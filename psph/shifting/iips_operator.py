"""The IIPS operator (compute.iips) as a PETSc matrix: assembled, or applied matrix-free.

`iips.operator = "assembled"`: a distributed AIJ matrix with block size d (BAIJ with
`-iips_mat_type baij`) on the pattern built once per neighbour-list rebuild, its values rewritten at every
Newton iteration; any preconditioner (`-iips_pc_type hypre`, `gamg`, `sor`, ...).

`iips.operator = "matrix_free"` (and "auto", the default, when the preconditioner is Jacobi or none and no
`-iips_mat_type` is given): a PETSc Python matrix whose product is computed from the pairs' Hessian blocks
(compute.iips.iips_pairs, iips_product): no pattern to build, d (d + 1) / 2 values per pair instead of
d^2 values and d^2 column indices in each direction, a pair of the rank's own unknowns stored once,
nothing stored for the lists' skin. Its halo unknowns come through a PETSc scatter built at each rebuild.
It provides its diagonal, so the preconditioner is Jacobi (the default) or none, and the transpose's
product, so any Krylov method works (`-iips_ksp_type gmres`, `tfqmr`, `bicg`, `cgne`, ...; LSQR breaks down
at once with Jacobi, on either operator, and needs `-iips_pc_type none`).

The operator is A = H diag(V), H the symmetric matrix of blocks HessW(x_i - x_j) (HessW is even and
symmetric) and V the volumes: A x = H (V x), and A^T x = V (H x).
"""

import weakref

import numpy as np

from psph.compute.iips import iips_pairs, iips_product, iips_structure, iips_values
from psph.errors import PsphError, UsageError
from psph.parallel.comm import allreduce_sum
from psph.solvers.aij import FixedPatternMatrix
from psph.solvers.linear import petsc_errors
from psph.solvers.petsc import petsc, petsc_comm

# preconditioners that need only the operator's product and diagonal
MATRIX_FREE_PCS = ("jacobi", "none")


class AssembledOperator:
    """The printed operator in a fixed-pattern AIJ / BAIJ matrix (solvers.aij)."""

    def __init__(self, prefix):
        self.prefix = prefix
        self.matrix = None
        self.mat = None

    def build(self, system, free) -> None:
        """The matrix of the owned particles in `free` after a neighbour-list rebuild (the previous one is
        freed first: its memory can serve the new one). Collective."""
        self.destroy()
        rows, _, n_free = system.global_rows(free)
        d = system.particles.dim
        try:
            indptr, indices, slot = iips_structure(rows, system.nbr_ptr, system.nbr_idx, d)
        except ValueError as err:  # more than 32-bit indices can address: run on more ranks
            raise PsphError(f"{err}; run on more ranks") from None
        n_total = int(allreduce_sum(system.comm, n_free))
        with petsc_errors("creating the IIPS matrix"):
            self.matrix = FixedPatternMatrix(system.comm, indptr, indices, slot, n_total * d, d, self.prefix)
        self.mat = self.matrix.mat

    def fill(self, system, volume) -> None:
        """The values at the current positions. Collective."""
        p = system.particles
        pos, vol, row, ptr, idx = p["position"], p[volume], p["row"], system.nbr_ptr, system.nbr_idx
        self.matrix.set_values(lambda where, diag, off: iips_values(pos, vol, row, ptr, idx, system.kernel.params,
                                                                    where, diag, off))

    def destroy(self) -> None:
        """Free the matrix now (petsc4py would keep it, and the arrays it was built on, alive). Collective."""
        if self.matrix is not None:
            self.matrix.destroy()
            self.matrix = self.mat = None


class MatrixFreeOperator:
    """The printed operator applied pair by pair, as a PETSc Python matrix (mult, getDiagonal)."""

    def __init__(self, prefix):
        self.prefix = prefix
        self.mat = None
        self.scatter = self.ghost = None
        # pair storage, kept from one rebuild to the next and grown when needed (fresh memory costs page faults)
        self.bcol = np.empty(0, dtype=np.int32)
        self.hess = np.empty((0, 1))

    def build(self, system, free) -> None:
        """Local numbering of the unknowns, the halo scatter and the Python matrix after a neighbour-list
        rebuild. Collective."""
        PETSc = petsc()
        self.destroy()
        rows, first, n_free = system.global_rows(free)
        d = system.particles.dim
        n_total = int(allreduce_sum(system.comm, n_free))
        # unknown block of every local particle: own rows (periodic images of own particles too) 0..n_free - 1,
        # other ranks' rows n_free.. in increasing global order, fixed particles -1
        self.col = np.full(len(rows), -1, dtype=np.int32)
        own = (rows >= first) & (rows < first + n_free)
        self.col[own] = rows[own] - first
        other = (rows >= 0) & ~own
        ghost_rows, ghost_of = np.unique(rows[other], return_inverse=True)
        self.col[other] = n_free + ghost_of
        entries = int(system.nbr_ptr[system.particles.n_owned])
        width = d * (d + 1) // 2
        if entries > len(self.bcol) or self.hess.shape[1] != width:
            capacity = max(entries, int(1.25 * len(self.bcol)))
            self.bcol = np.empty(capacity, dtype=np.int32)
            self.hess = np.empty((capacity, width))
        self.bptr = np.empty(n_free + 1, dtype=np.int64)
        self.x = np.empty((n_free + len(ghost_rows), d))  # the product's input: own unknowns, then the ghosts
        self.volume = np.empty(len(self.x))  # V_j of the same unknowns
        self.h0 = float(system.kernel.radial(np.zeros(1))[0])  # H's diagonal, W''(0) = f(0)
        with petsc_errors("creating the matrix-free IIPS operator"):
            self.ghost = PETSc.Vec().createWithArray(self.x[n_free:].ravel(), comm=PETSc.COMM_SELF)
            if system.comm.size > 1:
                layout = PETSc.Vec().createMPI((n_free * d, n_total * d), bsize=d, comm=petsc_comm(system.comm))
                index = PETSc.IS().createBlock(d, ghost_rows.astype(PETSc.IntType), comm=PETSc.COMM_SELF)
                self.scatter = PETSc.Scatter().create(layout, index, self.ghost, None)
                index.destroy()
                layout.destroy()
            self.mat = PETSc.Mat().createPython(((n_free * d, n_total * d), (n_free * d, n_total * d)),
                                                context=_PythonMatrix(self), comm=petsc_comm(system.comm))
            self.mat.setOptionsPrefix(self.prefix)
            self.mat.setUp()

    def fill(self, system, volume) -> None:
        """The pairs' Hessian blocks at the current positions, and the volumes. Collective (assembly marks the
        operator changed, so that the preconditioner takes the new diagonal)."""
        p = system.particles
        iips_pairs(p["position"], self.col, system.nbr_ptr, system.nbr_idx, system.kernel.params,
                   system.kernel.support, self.bptr, self.bcol, self.hess)
        free = self.col >= 0
        self.volume[self.col[free]] = p[volume][free]
        self.mat.assemble()

    def product(self, x, y, transpose=False) -> None:
        """y = A x = H (V x), or A^T x = V (H x) (PETSc vectors). Collective (the halo scatter)."""
        n, d = len(self.bptr) - 1, self.x.shape[1]
        self.x[:n] = x.array_r.reshape(n, d)
        if self.scatter is not None:
            self.scatter.scatter(x, self.ghost)
        if not transpose:
            self.x *= self.volume[:, None]
        out = y.array.reshape(n, d)
        iips_product(self.h0, self.bptr, self.bcol, self.hess, self.x, out)
        if transpose:
            out *= self.volume[:n, None]

    def destroy(self) -> None:
        """Free the PETSc objects of the last build. Collective."""
        for obj in (self.mat, self.scatter, self.ghost):
            if obj is not None:
                obj.destroy()
        self.mat = self.scatter = self.ghost = None


class _PythonMatrix:
    """PETSc's Python-matrix protocol for a MatrixFreeOperator (petsc4py calls these by name)."""

    def __init__(self, operator):
        # a weak reference: PETSc's matrix holds this context, so a strong one would make a cycle through C that
        # Python's collector cannot see, and a dropped operator (and its pair arrays) would never be freed
        self.operator = weakref.proxy(operator)

    def mult(self, mat, x, y) -> None:
        self.operator.product(x, y)

    def multTranspose(self, mat, x, y) -> None:  # noqa: N802 (PETSc's name)
        self.operator.product(x, y, transpose=True)

    def getDiagonal(self, mat, diagonal) -> None:  # noqa: N802 (PETSc's name)
        op = self.operator  # V_i HessW(0) = V_i W''(0) I, the printed self term
        diagonal.array[:] = np.repeat(op.h0 * op.volume[:len(op.bptr) - 1], op.x.shape[1])


OPERATORS = {"assembled": AssembledOperator, "matrix_free": MatrixFreeOperator}


def assembly_needed(prefix, pc=None):
    """What, in PETSc's options database (the command line, PETSC_OPTIONS, options files), asks for entries
    the matrix-free operator does not have, as the options to name (None: nothing). pc: the preconditioner's
    type of a set-up solver; without one, -<prefix>pc_type, or Jacobi, psph's default."""
    options = petsc().Options()
    if pc is None:
        pc = options.getString(f"{prefix}pc_type", "jacobi").lower()
    jacobi = options.getString(f"{prefix}pc_jacobi_type", "diagonal").lower()
    if pc not in MATRIX_FREE_PCS:
        return f"-{prefix}pc_type {pc}"
    if pc == "jacobi" and jacobi != "diagonal":
        return f"-{prefix}pc_type jacobi -{prefix}pc_jacobi_type {jacobi}"
    return None


def assembles(kind, prefix, pc=None) -> bool:
    """Whether iips.operator `kind` resolves to the assembled matrix under PETSc's options (iips_operator)."""
    if kind == "auto":
        return assembly_needed(prefix, pc) is not None or petsc().Options().hasName(f"{prefix}mat_type")
    return kind == "assembled"


def iips_operator(kind, solver):
    """The operator `kind` (iips.operator) for `solver` (a LinearSolver). "auto" is matrix-free where the
    preconditioner needs only the operator's diagonal (`-iips_pc_type jacobi` on the diagonal, or none) and no
    `-iips_mat_type` is given, assembled otherwise; an explicit "matrix_free" refuses a preconditioner that
    needs more, naming the option."""
    prefix = solver.prefix
    options = petsc().Options()
    pc = solver.ksp.getPC().getType()
    needs = assembly_needed(prefix, pc)
    if kind == "matrix_free" and needs is not None:
        raise UsageError(f"{needs}: iips.operator = \"matrix_free\" provides no entries but the diagonal; "
                         f"use -{prefix}pc_type jacobi or none, or iips.operator = \"assembled\"")
    if kind == "matrix_free" and options.hasName(f"{prefix}mat_type"):
        raise UsageError(f"-{prefix}mat_type {options.getString(f'{prefix}mat_type', '')}: iips.operator = "
                         "\"matrix_free\" builds no matrix; drop the option, or use iips.operator = \"assembled\"")
    return OPERATORS["assembled" if assembles(kind, prefix, pc) else "matrix_free"](prefix)
