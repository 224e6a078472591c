"""Krylov solves through PETSc KSP objects with an options prefix.

Code defaults (type, preconditioner, tolerances) are set first and `setFromOptions` is called last, so
every `-<prefix>ksp_*` / `-<prefix>pc_*` option given on the command line wins without code changes.
After each solve the converged reason is checked; a divergence raises SolverError with the reason name
and the iteration count.
"""

import re
from contextlib import contextmanager

import numpy as np
from mpi4py import MPI

from psph.errors import PsphError, SolverError, UsageError
from psph.profiling import phase
from psph.solvers.petsc import petsc, petsc_comm, viewer_file

# PETSc's error codes an option can cause (petscerror.h): PETSC_ERR_SUP, _ARG_WRONG, _ARG_OUTOFRANGE,
# _ARG_INCOMP, _USER (hypre's unknown option values), _ARG_UNKNOWN_TYPE, _MISSING_FACTOR (a factorization no
# installed package provides: -pc_type ilu on 2 ranks, an unknown -pc_factor_mat_solver_type): raised by
# collective set-up calls from the options every rank shares, so on every rank
OPTION_ERRORS = (56, 62, 63, 75, 83, 86, 92)
# PETSC_ERR_FILE_OPEN, _FILE_READ, _FILE_WRITE: an option's file (-iips_ksp_monitor ascii:PATH), which only
# some ranks may open
FILE_ERRORS = (65, 66, 67)
# PETSC_ERR_NOT_CONVERGED: a solve that -ksp_error_if_not_converged makes raise, which psph handles as the
# diverged solve it would have returned (iips.on_failure; it exited 1 with no step named: a PETSc-options audit)
NOT_CONVERGED = 91
TRACE = re.compile(r"\w+\(\) at ")
# iterations a trial solve may take where the run tolerates capped solves (LinearSolver.trial: capped)
TRIAL_MAX_IT = 1000


@contextmanager
def petsc_errors(what: str, options_collective: bool = True):
    """Turn a PETSc error into a one-line PsphError: a UsageError (exit 2) for a bad option (OPTION_ERRORS) or
    an option's file (FILE_ERRORS). Only the option errors are marked collective (raised on every rank, the
    CLI exits cleanly), and only with options_collective; any other may be one rank's, and the CLI aborts
    every rank. A run's solves pass options_collective=False: their options have passed the trial solve, so
    an error with one of those codes there (an argument out of range, an unsupported case) may come from
    one rank's data, and a clean exit of that rank alone would leave the others waiting in the solve."""
    PETSc = petsc()
    try:
        yield
    except PETSc.Error as exc:
        # PETSc's text: "error code N", then "[rank] Function() at file:line" frames and its messages
        lines = [ln.split("]", 1)[-1].strip() for ln in str(exc).splitlines()[1:]]
        messages = [ln.split(": https:", 1)[0] for ln in lines if ln and not TRACE.match(ln)]
        detail = "; ".join(messages) or str(exc).strip()
        # a bad option or an option's file is bad input (exit 2); any other PETSc error (memory, a library, a
        # bug) exits 1
        kind = UsageError if exc.ierr in OPTION_ERRORS + FILE_ERRORS else PsphError
        err = kind(f"PETSc failed in {what} (error {exc.ierr}): {detail}; check the command-line PETSc options")
        err.collective = options_collective and exc.ierr in OPTION_ERRORS
        raise err from None


# preconditioners whose preconditioned residual is the true one scaled by a (nearly uniform) diagonal, and the
# true residual over |b| above which a converged solve counts as loose (LinearSolver._check_true_residual)
DIAGONAL_PCS = ("jacobi", "pbjacobi", "none")
LOOSE_RESIDUAL = 0.5
# options whose value may name a viewer's file (LinearSolver._append_to_viewer_files), and the files emptied
VIEWERS = r"view|monitor|converged_reason|converged_rate"
VIEWER_OPTIONS = re.compile(VIEWERS)
_EMPTIED = set()
# options that make a solve print, or raise where it would return a diverged reason, at any level (the inner
# solvers' -iips_sub_ksp_view, -iips_mg_levels_ksp_monitor, ...); a trial solve is done without them
OUTPUT_OPTIONS = re.compile(VIEWERS + r"|compute_eigenvalues|compute_singularvalues|print_statistics|"
                            r"error_if_not_converged")


@contextmanager
def _without_output_options(prefix):
    """Take the options of prefix `prefix` that make a solve print or raise (OUTPUT_OPTIONS) out of the
    database while the body runs, and put them back after it."""
    options = petsc().Options()
    held = {k: v for k, v in options.getAll().items() if k.startswith(prefix) and OUTPUT_OPTIONS.search(k)}
    for key in held:
        options.delValue(key)
    try:
        yield
    finally:
        for key, value in held.items():
            options.setValue(key, value)


def reason_name(reason: int) -> str:
    table = petsc().KSP.ConvergedReason
    for name in dir(table):
        if not name.startswith("_") and getattr(table, name) == reason and name != "ITERATING":
            return name
    return str(reason)


class LinearSolver:
    """A KSP with prefix `prefix` (e.g. 'iips_') and code defaults the command line can override."""

    def __init__(self, comm, prefix: str, *, ksp_type="bcgs", pc_type="jacobi", rtol=1e-2, atol=1e-50,
                 max_it=10000, initial_guess_nonzero=False):
        """Create the KSP on comm. Collective."""
        self.comm = comm
        self.prefix = prefix
        self.defaults = dict(ksp_type=ksp_type, pc_type=pc_type, rtol=rtol, atol=atol, max_it=max_it,
                             initial_guess_nonzero=initial_guess_nonzero)
        self._append_to_viewer_files()
        self.ksp = self._create()
        self.operator_sizes = None  # of the current operator (which a caller may have freed since)
        self.iterations = 0
        self.checked_solves = self.loose_solves = 0  # _check_true_residual
        self.worst_residual = 0.0

    def _append_to_viewer_files(self) -> None:
        """Make this solver's viewer options that name an ASCII file (-<prefix>ksp_monitor ascii:PATH,
        -<prefix>ksp_view :PATH:ascii_info, ...) append to it, emptied once per process at the first solver's
        set-up: PETSc opens such a file for writing, which empties it, whenever a KSP is set up from the
        options, and each neighbour-list rebuild makes a new KSP (_renew): the file held the last rebuild's
        lines, or none (a PETSc-options audit). A mode the option gives itself is kept. A file rank 0 cannot
        write (one named in an options file or PETSC_OPTIONS, which check_viewer_files does not see) is a
        UsageError on every rank. Collective."""
        options = petsc().Options()
        failed = None
        for key, value in options.getAll().items():
            fields = viewer_file(value) if key.startswith(self.prefix) and isinstance(value, str) else None
            if fields is None or fields[0] not in ("", "ascii") or not VIEWER_OPTIONS.search(key) or fields[3]:
                continue
            if fields[1] not in _EMPTIED and self.comm.rank == 0 and failed is None:
                try:
                    open(fields[1], "w").close()
                except OSError as err:
                    failed = f"-{key} {value}: cannot write {fields[1]!r} ({err.strerror})"
            _EMPTIED.add(fields[1])
            options.setValue(key, ":".join(fields[:3] + ["append"]))
        failed = self.comm.bcast(failed, root=0)  # (emptied before any rank's KSP opens it)
        if failed:
            raise UsageError(failed)

    def _create(self, settings=None):
        """A KSP with `settings` (the code defaults unless given), then the options database's (which win)."""
        PETSc = petsc()
        d = settings or self.defaults
        with petsc_errors(f"setting up the -{self.prefix} solver"):
            ksp = PETSc.KSP().create(comm=petsc_comm(self.comm))
        try:
            with petsc_errors(f"setting up the -{self.prefix} solver"):
                ksp.setOptionsPrefix(self.prefix)
                ksp.setType(d["ksp_type"])
                ksp.getPC().setType(d["pc_type"])
                ksp.setTolerances(rtol=d["rtol"], atol=d["atol"], max_it=d["max_it"])
                ksp.setInitialGuessNonzero(d["initial_guess_nonzero"])
                ksp.setFromOptions()
                # setFromOptions stores -<prefix>ksp_rtol 1.5 or -1 as given; set again, PETSc checks them now
                # (else the first set-up that copies them, _renew, fails mid-run)
                rtol, atol, divtol, max_it = ksp.getTolerances()
                ksp.setTolerances(rtol=rtol, atol=atol, divtol=divtol, max_it=max_it)
        except PsphError:  # now, not when the error's traceback is collected (petsc.petsc_comm)
            ksp.destroy()
            raise
        return ksp

    def set_operator(self, mat) -> None:
        """Use `mat` from now on. A matrix of another size (after a neighbour-list rebuild) gets a fresh
        KSP (_renew): some preconditioners (GAMG) cannot be reset to new sizes. Collective: the local sizes
        may change on some ranks only, and creating a KSP is collective, so the ranks decide together."""
        changed = self.operator_sizes is not None and self.operator_sizes != mat.getSizes()
        if self.comm.allreduce(changed, op=MPI.LOR):
            self._renew()
        with petsc_errors(f"setting up the -{self.prefix} solver"):
            self.ksp.setOperators(mat)
        self.operator_sizes = mat.getSizes()

    def release_operator(self) -> None:
        """Let go of the operator and of what the set-up built from it, so that an operator about to be
        replaced is freed before its successor is built rather than after: a fresh KSP (_renew; KSPReset
        would also drop the viewers of -<prefix>ksp_view and the like, and -<prefix>ksp_converged_rate then
        crashes the next solve). The next set_operator takes any size. Collective."""
        self._renew()
        self.operator_sizes = None

    def _renew(self) -> None:
        """Replace the KSP by a fresh one of its types and tolerances (options set only while the solver was
        built, as a program or test may do, are gone from the database by then), and the options database's.
        Collective."""
        rtol, atol, _, max_it = self.ksp.getTolerances()
        settings = dict(ksp_type=self.ksp.getType(), pc_type=self.ksp.getPC().getType(), rtol=rtol,
                        atol=atol, max_it=max_it, initial_guess_nonzero=self.ksp.getInitialGuessNonzero())
        self.ksp.destroy()
        self.ksp = None  # (if _create fails, destroy must not touch the destroyed KSP: PETSc would crash)
        self.ksp = self._create(settings)

    def _check_true_residual(self, b, x) -> None:
        """Count a converged solve whose true residual |b - A x| stayed above LOOSE_RESIDUAL |b| (loose_solves,
        worst_residual): where the preconditioner is not diagonal and preconditions from the left, PETSc's
        test measures the preconditioned residual, which ILU, block Jacobi, ASM or Euclid brought down while
        the true one stayed at 0.996 |b| (a PETSc-options audit: the static case ended at L2(grad C) 3.4e-3
        against Jacobi's 1.4e-4, with exit 0 and no word). One more operator product per such solve; none
        with Jacobi (the default), whose diagonal is V_i W''(0): nearly uniform. Collective."""
        PETSc = petsc()
        if self.ksp.getPC().getType() in DIAGONAL_PCS or self.ksp.getPCSide() != PETSc.PC.Side.LEFT \
                or self.ksp.getNormType() != PETSc.KSP.NormType.PRECONDITIONED:
            return
        scale = b.norm()
        if scale == 0.0:
            return
        r = b.duplicate()
        try:
            self.ksp.getOperators()[0].mult(x, r)
            r.aypx(-1.0, b)
            ratio = r.norm() / scale
        finally:
            r.destroy()
        self.checked_solves += 1
        if ratio > LOOSE_RESIDUAL:
            self.loose_solves += 1
            self.worst_residual = max(self.worst_residual, ratio)

    def loose_warning(self):
        """The warning about loose solves (_check_true_residual), or None."""
        if not self.loose_solves:
            return None
        pc = self.ksp.getPC().getType()
        return (f"{self.loose_solves} of {self.checked_solves} -{self.prefix} solves met their tolerance in the "
                f"preconditioned residual while the true residual |b - A x| stayed up to {self.worst_residual:.2g} "
                f"|b| (PC {pc}, preconditioned from the left): their steps were rough; -{self.prefix}ksp_pc_side "
                f"right makes PETSc test the true residual, and Jacobi (the default) preconditions this operator well")

    def solve(self, b, x, trial=False) -> int:
        """Solve operator x = b (x holds the initial guess); returns iterations or raises SolverError. trial:
        the trial solve (see trial()), where an option's error is the options' and so every rank's."""
        stopped = False
        with phase("ksp_solve"), petsc_errors(f"the -{self.prefix} solve", options_collective=trial):
            try:
                self.ksp.solve(b, x)
            except petsc().Error as exc:  # -<prefix>ksp_error_if_not_converged (of this solver or an inner one)
                if exc.ierr != NOT_CONVERGED:
                    raise
                stopped = True
        reason = self.ksp.getConvergedReason()
        its = self.ksp.getIterationNumber()
        self.iterations += its
        name = self.prefix.rstrip("_") or "linear"
        error = None
        if reason < 0:
            error = SolverError(name, reason_name(reason), its)
        elif stopped:  # an inner solver's, mid-iteration (maybe on some ranks only): its reason is not this KSP's
            error = SolverError(name, "an inner solver did not converge (its -..._error_if_not_converged)", its)
        elif not np.isfinite(x.norm()):  # collective: every rank sees the same norm
            error = SolverError(name, "DIVERGED_NANORINF", its)
        elif not trial:
            self._check_true_residual(b, x)
        if error is not None:
            # reason and norm are global: every rank raises it; an inner solver's error may be some ranks' only,
            # which the command line then ends by MPI_Abort
            error.collective = reason < 0 or not stopped
            raise error
        return its

    def trial(self, mat, capped=False) -> None:
        """Solve `mat` x = 1 once with this solver's types and options, quietly (no monitor, view or converged-
        reason output), so that what PETSc refuses only at a first solve (GAMG on a BAIJ matrix, a Krylov
        method that breaks down with its preconditioner) is found before a run touches its output. capped: the
        run tolerates a solve that reaches its max_it (iips.on_failure = "reject" undoes the call), so a small
        -{prefix}ksp_max_it is a choice, and the trial may take TRIAL_MAX_IT iterations; otherwise a max_it too
        small for the test system is refused. A failure is bad input: a UsageError naming the solver's
        options. For a solver about to be dropped: its KSP is made anew without those options (PETSc takes its
        viewers and monitors from the options when a KSP is set up from them). Collective."""
        b, x = mat.createVecs()
        b.set(1.0)
        x.set(0.0)
        described = f"prefix -{self.prefix}"
        try:
            with _without_output_options(self.prefix):
                self.ksp.destroy()
                self.ksp = None  # (describe must not touch a destroyed KSP: PETSc would crash)
                self.ksp = self._create()
                described = self.describe()  # the options' max_it, before the trial's
                if capped:
                    self.ksp.setTolerances(max_it=max(self.ksp.getTolerances()[3], TRIAL_MAX_IT))
                self.set_operator(mat)
                self.solve(b, x, trial=True)
        except PsphError as err:  # on a well-posed system any failure is the options'
            if isinstance(err, UsageError):
                raise
            advice = "" if str(err).endswith("PETSc options") else "; check the command-line PETSc options"
            usage = UsageError(f"the -{self.prefix} solver ({described}) fails on a small well-posed test "
                               f"system: {err}{advice}")
            usage.collective = getattr(err, "collective", False)  # a PETSc error may be some ranks' only
            raise usage from None
        finally:
            b.destroy()
            x.destroy()

    def destroy(self) -> None:
        """Free the KSP now (a trial whose set-up failed may have left none). Collective."""
        if self.ksp is not None:
            self.ksp.destroy()

    def describe(self) -> str:
        pc = self.ksp.getPC()
        rtol, atol, _, max_it = self.ksp.getTolerances()
        return f"KSP {self.ksp.getType()} + PC {pc.getType()}, rtol {rtol:g}, max_it {max_it}"
