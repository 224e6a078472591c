"""Implicit iterative particle shifting (IIPS) on PETSc (thesis 000, chapter 8; distributed as its
section 11.2 proposes).

Each Newton iteration assembles the printed operator of thesis eq. 8.11 / 8.32 (compute.iips) in a
distributed PETSc AIJ matrix with block size d (BAIJ with `-iips_mat_type baij`), built once per
neighbour-list rebuild, or applies it matrix-free (`iips.operator`, shifting.iips_operator), solves
A dx = grad C with the KSP of prefix `iips_` (default BCGS + Jacobi, rtol 1e-2, thesis section 8.3.1;
any `-iips_ksp_*` / `-iips_pc_*` option overrides them) and moves the free particles by dx.

Initial guess: the first Newton iteration of a call starts from each particle's first step of the
previous call (field `iips_first_step`, which follows the particle through rebuilds, migrations and
checkpoints) if that guess has a smaller residual than zero; later iterations start from zero. From one
time step to the next the corrections are alike (Taylor-Green, dx = 0.025, IIPS + NFTS: 36% fewer KSP
iterations, no stalled call instead of 3); within a call the steps shrink and a previous step is a worse
guess than zero. `-iips_ksp_initial_guess_nonzero 0` starts every solve from zero (the thesis).

Triggering and stopping (thesis Algorithms 1-3, eq. 8.34-8.35):
- threshold on Linf(grad C) = h max_i |grad C_i| (thesis eq. 3.5): absolute (`iips.threshold`) or
  beta times the value after a static pre-procedure of `iips.pre_newton` iterations (`iips.beta`);
- Procedure A: at least one Newton iteration per call, then more while above the threshold;
  Procedure B: iterate only while above the threshold;
- at most `iips.max_newton` iterations per call, and none from a distribution level to round-off
  (Linf(grad C) <= ROUNDOFF_LINF = 1e-12, whatever the procedure). With a threshold, not reaching it is a
  stall: by default (`iips.on_stall = "best"`) the call keeps its iterate of lowest Linf(grad C) (with
  `iips.stall_max_shift = c`, of those that move no particle farther than c h; the start qualifies) and
  the stall is reported and counted, as the thesis caps the iterations for cost (section 10.1.1). The
  printed operator is not the exact Jacobian (seeds/README.md), so near the threshold the iteration can
  wander instead of converging. Growth of Linf(grad C) by `iips.divergence_factor` within a call, from
  DIVERGENCE_FLOOR = 1e-4 at least (growth from round-off is none), is a divergence; it and a diverged
  linear solve stop the run (`iips.on_failure = "stop"`), or undo the call's displacements and carry on
  (`"reject"`), reported either way.
- step control (`iips.backtrack = k`, default 0): a step that raises L2(grad C) is halved up to k times,
  and undone if L2 still rises, which ends the call: a stall (iips.on_stall) above the threshold. Accepted
  iterates then never raise L2, so the divergence check above seldom fires (Linf can still grow).
"""

import time
from dataclasses import replace

import numpy as np

from psph.boundaries.free_surface import NoFreeSurface
from psph.errors import NumericalError, SceneError, SolverError
from psph.parallel.comm import allreduce_max, allreduce_sum
from psph.particles import SCRATCH_FIELDS, FieldSpec
from psph.profiling import phase
from psph.scene.schema import ROUNDOFF_LINF
from psph.shifting.base import Shifting, ShiftReport, measure, steepest
from psph.shifting.iips_operator import AssembledOperator, iips_operator
from psph.solvers.aij import chain_matrix, check_mat_type, family_of
from psph.solvers.linear import LinearSolver, petsc_errors
from psph.solvers.petsc import destroy_at_exit, petsc

SHIFT_FIELD = FieldSpec("iips_shift", ("d",))
LEVEL_LINF = 1e-9  # Linf(grad C) of a distribution level to round-off (a lattice: 4e-15; relaxed: about 1e-5)
# the call's displacement at its iterate of lowest Linf(grad C) (a field: it migrates with the particles)
BEST_FIELD = FieldSpec(SCRATCH_FIELDS[0], ("d",), scratch=True)
# each particle's first Newton step of the last call: the next call's initial guess
GUESS_FIELD = FieldSpec(SCRATCH_FIELDS[1], ("d",), scratch=True)
# the last Newton step (iips.backtrack halves it back; a field, so that it follows the particles)
STEP_FIELD = FieldSpec(SCRATCH_FIELDS[2], ("d",), scratch=True)
# block rows of the trial system (trial), shared by the ranks, and the fewest a rank takes: 16 for the matrix types
# written generically (SELL mangled 4 rows per rank on 3 ranks). The same system on up to 12 (3) ranks: with 4
# block rows per rank, -iips_ksp_max_it 2 -iips_ksp_rtol 1e-10 passed the trial on 1 rank and not on 2 (a ranks
# audit; at rtol 1e-10 BCGS + Jacobi takes 2 iterations at 4 block rows, 4 at 8, 11 at 48; 2 at rtol 1e-2)
TRIAL_BLOCKS = 48
TRIAL_ROWS = 4
TRIAL_ROWS_GENERIC = 16
# particles closer than COINCIDENT h count as coincident and are first nudged NUDGE h apart
COINCIDENT = 1e-6
NUDGE = 1e-3
# growth is measured from at least this Linf(grad C), a relaxed distribution's level (1e-5 to 1e-4; a lattice's
# is ~1e-14): growth from round-off to below divergence_factor x this is no divergence (a new user's flow with
# iips.threshold = 0 stopped on "divergence" from 1.4e-6 to 1.7e-4, below any threshold one would set)
DIVERGENCE_FLOOR = 1e-4
PREFIX = "iips_"  # the options prefix of the IIPS solver and matrix


class ImplicitShifting(Shifting):
    name = "iips"

    def __init__(self, spec, comm, volume="volume", surface=None):
        """volume: the field whose values weight the concentration C = sum_j W_ij V_j that IIPS levels and
        its operator (thesis eq. 6.12, 8.6, 8.11: omega_j): the particle volumes, or "volume0", the constant
        reference volumes, under a field update that makes the volumes follow the displacements (NFTS: see
        psph.shifting.field_update.FictitiousTimeStep)."""
        self.spec = spec
        self.volume = volume
        self.surface = NoFreeSurface() if surface is None else surface
        self.solver = LinearSolver(comm, PREFIX, ksp_type="bcgs", pc_type="jacobi", rtol=1e-2,
                                   initial_guess_nonzero=True)
        self.operator = iips_operator(spec.operator, self.solver)
        # -iips_ksp_initial_guess_nonzero (default on): start a call's first solve from the stored guess. The
        # KSP's own flag is then set per solve, on only when the solve starts from a guess. With it on, PETSc
        # skips the product A x0 of the initial residual only while x0's cached norm shows it zero, which
        # setting a (zero or rejected) guess's array loses: a call's first solve took 5 products for 2 BCGS
        # iterations instead of 4
        self.use_guess = self.solver.ksp.getInitialGuessNonzero()
        self.threshold = spec.threshold if spec.threshold > 0.0 else None
        self.initial_linf = None  # Linf(grad C) after the pre-procedure (thesis: Linf(grad C)_Init)
        self.pre_iterations = 0
        self._structure_of = None
        self._unknowns_moved = False  # a free-surface detection changed the unknowns: rebuild the structure
        self.calls = 0
        self.newton_iterations = 0
        self.rejections = 0
        self.failures = 0
        destroy_at_exit(self)  # a script that never calls destroy() must not crash at exit

    COUNTERS = ("threshold", "initial_linf", "calls", "newton_iterations", "rejections", "failures")

    def checkpoint_state(self) -> dict:
        """Threshold state and counters (what a restart needs; the matrix is rebuilt)."""
        return {name: getattr(self, name) for name in self.COUNTERS}

    def restore(self, state: dict) -> None:
        for name in self.COUNTERS:
            setattr(self, name, state[name])

    # ------------------------------------------------------------- assembly
    def _structure(self, system):
        """(Re)build the operator after a neighbour-list rebuild: numbering, pattern or halo scatter. Collective."""
        free = self.surface.unknowns(system)
        with phase("iips_structure"):
            # the previous vectors and operator first, the solver's hold on it included: their memory can serve
            # the new ones (an assembled matrix the KSP still held stayed alive through the build: 1536 MiB
            # peak for 160 000 particles in 2-D, one rank, instead of 1083)
            self._free_structure()
            self.operator.build(system, free)
        self.mat = self.operator.mat
        self.rhs, self.dx = self.mat.createVecs()
        self.residual = self.rhs.duplicate()  # work vector of _start_from
        self.free = free
        # the owned rows of the unknowns: a slice, a view rather than a copy, when every owned particle is one
        self.rows = slice(None) if free.all() else free
        self.solver.set_operator(self.mat)
        self._structure_of = system.rebuilds
        self._unknowns_moved = False

    def _detect_surface(self, system) -> int:
        """Detect the free surface (if any) for this call; mark the structure stale if that changed the unknowns
        on some rank. Returns the global number of unknowns. Collective."""
        self.surface.detect(system)
        unknowns = self.surface.unknowns(system)
        if self.surface.active and self._structure_of is not None:
            changed = len(unknowns) != len(self.free) or not np.array_equal(self.free, unknowns)
            self._unknowns_moved = bool(allreduce_max(system.comm, int(changed)))
        return int(allreduce_sum(system.comm, int(np.count_nonzero(unknowns))))

    def assemble(self, system):
        """Fill the IIPS operator at the current positions. Collective."""
        if self._structure_of != system.rebuilds or self._unknowns_moved:
            self._structure(system)
        with phase("iips_assemble"):
            self.operator.fill(system, self.volume)
        return self.mat

    # -------------------------------------------------------------- iterate
    def newton_iteration(self, system, grad, first=False) -> int:
        """One Newton iteration from the current grad C: assemble, solve, move. Returns KSP iterations.
        first: the call's first iteration (starts from, and records, the guess of GUESS_FIELD). Collective."""
        self.assemble(system)
        d = system.particles.dim
        p = system.particles
        rows = self.rows
        self.rhs.setArray(grad[rows].ravel())
        guess = first and self.use_guess
        self.dx.set(0.0)
        started = guess and self._start_from(p.owned(GUESS_FIELD.name)[rows].ravel())
        self.solver.ksp.setInitialGuessNonzero(started)
        its = self.solver.solve(self.rhs, self.dx)
        step = self.dx.getArray(readonly=True).reshape(-1, d)
        if guess:
            p.owned(GUESS_FIELD.name)[rows] = step
            p.owned(GUESS_FIELD.name)[~self.free] = 0.0  # no stale guess for a particle that becomes free later
        p.owned("position")[rows] += step
        p.owned(SHIFT_FIELD.name)[rows] += step
        if self.spec.backtrack:
            p.owned(STEP_FIELD.name)[:] = 0.0
            p.owned(STEP_FIELD.name)[rows] = step
        self.newton_iterations += 1
        system.update()
        return its

    def _start_from(self, guess) -> bool:
        """Start the solve from `guess` if it is not zero (a static run's one call has none) and its residual
        is smaller than zero's (|b - A g| < |b|; not so after a pre-procedure, whose large first step is no
        guess for a flow's small corrections). Returns whether dx holds the guess (else zero). Collective."""
        self.dx.setArray(guess)
        if self.dx.norm(petsc().NormType.INFINITY) == 0.0:
            return False
        self.mat.mult(self.dx, self.residual)
        self.residual.aypx(-1.0, self.rhs)
        if self.residual.norm() >= self.rhs.norm():
            self.dx.set(0.0)
            return False
        return True

    def prepare(self, system, on_iteration=None):
        """Static pre-procedure (`iips.pre_newton` iterations) and the beta threshold (eq. 8.34). Collective."""
        system.particles.add_field(SHIFT_FIELD)
        system.particles.add_field(GUESS_FIELD)
        if self.spec.pre_newton > 0:
            lowest = [np.inf]

            def track(info):  # the lowest iterate (iips.beta_from = "lowest")
                lowest[0] = min(lowest[0], info["Linf_grad_c"])
                return on_iteration(info) if on_iteration is not None else None

            # a failure stops the run whatever iips.on_failure says: "reject" undid the whole pre-procedure, and
            # the beta threshold then came from the unrelaxed start, which no call reached (a PETSc-options audit:
            # no Newton iteration in 50 steps, exit 0)
            report = self._iterate(system, self.spec.pre_newton, None, False, track, {}, on_failure="stop")
            last = report.Linf_grad_c
            self.set_initial_linf(min(lowest[0], last) if self.spec.beta_from == "lowest" else last)
            # fewer where iips.backtrack found no descent (counting the undone iteration)
            self.pre_iterations = report.iterations
        return self.initial_linf

    def set_initial_linf(self, linf) -> None:
        """Linf(grad C) after the pre-procedure (thesis: Linf(grad C)_Init), and the threshold beta x it
        (eq. 8.34) when `iips.beta` is given."""
        self.initial_linf = linf
        if self.spec.beta > 0:
            self.threshold = self.spec.beta * linf
            if self.threshold < ROUNDOFF_LINF:  # an audit: 9 calls of 10 stalled at 20 iterations, exit 0
                # (the hint told of a lattice for a tiny beta too, an audit: a relaxed start leaves about 1e-5)
                level = linf < LEVEL_LINF
                raise SceneError("iips.beta", f"{self.spec.beta:g} x Linf(grad C) after the pre-procedure "
                                 f"({linf:.3g}) = {self.threshold:.3g} is below round-off ({ROUNDOFF_LINF:g}), "
                                 "which no call reaches: " + (
                                     "the pre-procedure left a level distribution (a lattice?): give "
                                     "iips.threshold, or start from a perturbed one (initial.sigma_over_dx > 0)"
                                     if level else "give a larger iips.beta, or iips.threshold"))

    def _free_structure(self) -> None:
        """Free the vectors of the last structure, if any (petsc4py keeps them alive), and make the solver let
        go of its operator (LinearSolver.release_operator). Collective."""
        if self._structure_of is not None:
            for obj in (self.rhs, self.dx, self.residual):
                obj.destroy()
            self.solver.release_operator()
            self.mat = None
            self._structure_of = None

    def settings(self) -> dict:
        """The linear solver the options give (KSP, PC, tolerances) and the operator (iips.operator, "auto"
        decided), for the log and summary.json (`iips_solver`)."""
        ksp = self.solver.ksp
        rtol, atol, _, max_it = ksp.getTolerances()
        assembled = isinstance(self.operator, AssembledOperator)
        return {"ksp_type": ksp.getType(), "pc_type": ksp.getPC().getType(), "rtol": rtol, "atol": atol,
                "max_it": max_it, "operator": "assembled" if assembled else "matrix_free",
                "mat_type": petsc().Options().getString(f"{PREFIX}mat_type", "aij") if assembled else None}

    @staticmethod
    def describe_settings(s) -> str:
        operator = f"assembled {s['mat_type']} matrix" if s["operator"] == "assembled" else "matrix-free operator"
        return (f"KSP {s['ksp_type']} + PC {s['pc_type']}, rtol {s['rtol']:g}, max_it {s['max_it']}, "
                f"{operator} (PETSc options prefix -{PREFIX})")

    def trial(self, dim) -> None:
        """Solve once with this -iips_ solver on a small test system in `dim` dimensions (solvers.aij.chain_matrix,
        of the -iips_mat_type the assembled operator would have; the matrix-free operator's preconditioners need
        only a diagonal, which any type gives), so that a solver PETSc refuses only at a first solve stops a run
        before it touches its output (LinearSolver.trial; a -iips_ksp_max_it too small for the test system is
        refused unless iips.on_failure = "reject" undoes the calls it fails). The matrix-free operator's trial
        matrix is AIJ (it reads no -iips_mat_type, which the run does not read either). An assembled operator of a
        type other than AIJ or BAIJ (-iips_mat_type sell, dense) is checked first (solvers.aij.check_mat_type:
        SBAIJ and IS are refused) and tried on TRIAL_ROWS_GENERIC block rows per rank at least (PETSc 3.18's
        SELL mangles 4; GAMG on SELL or dense failed at the first IIPS call, after the run had written its
        output: a PETSc-options audit). The system has TRIAL_BLOCKS block rows, shared by the ranks (each takes
        at least its fewest). Collective."""
        assembled = isinstance(self.operator, AssembledOperator)
        fewest = TRIAL_ROWS
        if assembled and family_of(self.solver.prefix) is None:
            with petsc_errors("creating the IIPS matrix"):
                check_mat_type(self.solver.comm, self.solver.prefix)
            fewest = TRIAL_ROWS_GENERIC
        size, rank = self.solver.comm.size, self.solver.comm.rank
        rows = max(fewest, TRIAL_BLOCKS // size + int(rank < TRIAL_BLOCKS % size))
        matrix = chain_matrix(self.solver.comm, rows, dim, self.solver.prefix if assembled else "psph_trial_")
        try:
            self.solver.trial(matrix.mat, capped=self.spec.on_failure == "reject")
        finally:
            matrix.destroy()

    def destroy(self) -> None:
        """Free the PETSc operator, vectors and solver now. Collective."""
        self._free_structure()
        self.operator.destroy()
        self.solver.destroy()

    def correct(self, system, on_iteration=None, iterations=None, **where) -> ShiftReport:
        """One IIPS call (per time step, or a whole static run): Procedure A or B.

        on_iteration(info) is called after every Newton iteration; returning True ends the call early.
        `iterations` is accepted for symmetry with the explicit method; IIPS uses iips.max_newton.
        """
        system.particles.add_field(SHIFT_FIELD)
        system.particles.add_field(GUESS_FIELD)
        self.calls += 1
        return self._iterate(system, self.spec.max_newton, self.threshold, self.spec.procedure == "A",
                             on_iteration, where)

    def _iterate(self, system, max_newton, threshold, at_least_one, on_iteration, where,
                 on_failure=None) -> ShiftReport:
        """Newton iterations (see correct); on_failure: a divergence's or diverged solve's mode instead of
        iips.on_failure's."""
        p = system.particles
        p.owned(SHIFT_FIELD.name)[:] = 0.0
        h = system.kernel.h
        separated = system.separate_coincident(COINCIDENT * h, NUDGE * h)
        if self._detect_surface(system) == 0:  # a free-surface region covers all the fluid
            return ShiftReport(message="no IIPS unknowns: the free-surface region holds every fluid particle")
        grad, l2, linf = self.measure(system)
        start_linf = linf
        report = ShiftReport(L2_grad_c=l2, Linf_grad_c=linf)
        if separated:
            report.message = f"{separated} coincident particle(s) nudged apart by {NUDGE:g} h"
        failure = None
        p.add_field(BEST_FIELD)
        p.owned(BEST_FIELD.name)[:] = 0.0
        if self.spec.backtrack:
            p.add_field(STEP_FIELD)
        best_linf, best_iteration = linf, 0
        stuck = False
        while report.iterations < max_newton and not linf <= ROUNDOFF_LINF:  # (NaN iterates, and fails)
            above = threshold is None or linf > threshold
            if not (above or (at_least_one and report.iterations == 0)):
                break
            t0 = time.perf_counter()
            try:
                its = self.newton_iteration(system, grad, first=report.iterations == 0)
            except SolverError as err:  # its KSP iterations were done, and count
                failure = err
                report.linear_iterations += err.iterations
                where = self._place(system, grad, where)
                break
            previous = l2
            grad, l2, linf = self.measure(system)
            report.iterations += 1
            report.linear_iterations += its
            if self.spec.backtrack and l2 > previous:
                grad, l2, linf, stuck = self._backtrack(system, previous)
            report.L2_grad_c, report.Linf_grad_c = l2, linf
            if stuck:  # back at the step's start, which the best iterate has already counted
                break
            if linf < best_linf and (not self.spec.stall_max_shift
                                     or largest_shift(system) <= self.spec.stall_max_shift * h):
                best_linf, best_iteration = linf, report.iterations
                p.owned(BEST_FIELD.name)[:] = p.owned(SHIFT_FIELD.name)
            if not np.isfinite(linf) or linf > self.spec.divergence_factor * max(start_linf, DIVERGENCE_FLOOR):
                where = self._place(system, grad, where)
                failure = NumericalError(f"IIPS Newton iteration diverged: Linf(grad C) grew from "
                                         f"{start_linf:.3e} to {linf:.3e}", **where)
                break
            if on_iteration is not None and on_iteration(
                    {"newton": report.iterations, "ksp_iterations": its, "L2_grad_c": l2, "Linf_grad_c": linf,
                     "newton_time_s": time.perf_counter() - t0}):
                break
        mode = on_failure or self.spec.on_failure
        if failure is None and threshold is not None and linf > threshold and (report.iterations >= max_newton
                                                                               or stuck):
            mode = self.spec.on_stall
            where = self._place(system, grad, where, last=report.iterations)  # the last iterate, as described
            stalled = (f"IIPS Newton stalled: Linf(grad C) = {linf:.3e} above the threshold {threshold:.3e} after "
                       f"{report.iterations} iterations"
                       + (f" (no descent in {self.spec.backtrack} halvings)" if stuck else ""))
            if mode == "best":
                self._restore(system, p.owned(BEST_FIELD.name), report)
                report.kept_iteration = best_iteration
                stalled += f"; kept the iterate of Linf(grad C) = {report.Linf_grad_c:.3e}"
            failure = NumericalError(stalled, **where)
        if failure is not None:
            self._fail(system, report, failure, where, mode)
        elif stuck:
            ended = (f"IIPS call ended after {report.iterations} iterations: no descent in "
                     f"{self.spec.backtrack} halvings")
            report.message = f"{report.message}; {ended}" if report.message else ended
        return report

    def _place(self, system, grad, where, last=None) -> dict:
        """A failure's place: the call's `where` (a flow's step and time), else the system's (a static run's
        iteration in progress, which its driver keeps there; `last`: a failure of the last completed one), and
        the unknown of largest |grad C| over all ranks (the lowest gid of equals; a non-finite value counts as
        the largest): {"gid", "position"}. Collective."""
        place = {**system.where, **where, **steepest(system, grad, np.flatnonzero(self.surface.unknowns(system)))}
        if last is not None and "iteration" in place:
            place["iteration"] = last
        return place

    def measure(self, system):
        """(grad C, L2, Linf) over the unknowns. Collective."""
        return measure(system, self.volume, self.surface.unknowns(system))

    def _backtrack(self, system, previous):
        """The last Newton step raised L2(grad C) above `previous`: halve it back (iips.backtrack times at
        most) until L2 is at most `previous`; failing that, return to the step's start (stuck: the call ends,
        a stall if above the threshold). Returns (grad C, L2, Linf, stuck). Collective."""
        p = system.particles  # the step is a field: a rebuild in _move reorders the particles
        for halving in range(1, self.spec.backtrack + 1):
            self._move(system, -0.5 ** halving * p.owned(STEP_FIELD.name))
            grad, l2, linf = self.measure(system)
            if l2 <= previous:
                return grad, l2, linf, False
        self._move(system, -0.5 ** self.spec.backtrack * p.owned(STEP_FIELD.name))
        grad, l2, linf = self.measure(system)
        return grad, l2, linf, True

    def _move(self, system, by) -> None:
        """Move the owned particles by `by` (a field's values, or what follows them), their accumulated
        displacement with them. Collective."""
        p = system.particles
        p.owned("position")[:] += by
        p.owned(SHIFT_FIELD.name)[:] += by
        system.update()

    def _restore(self, system, shift, report):
        """Move the particles back to the iterate whose accumulated displacement is `shift` (None: the
        call's start) and re-measure. Collective."""
        p = system.particles
        current = p.owned(SHIFT_FIELD.name)
        p.owned("position")[:] -= current if shift is None else current - shift
        current[:] = 0.0 if shift is None else shift
        system.update()
        _, report.L2_grad_c, report.Linf_grad_c = self.measure(system)

    def _fail(self, system, report, failure, where, mode):
        """Stop (raise on all ranks), or reject (undo this call's displacements), warn (keep them) or best
        (already restored), and report it in the call's report (logged and counted by the drivers)."""
        if mode == "stop" or (mode == "warn" and isinstance(failure, SolverError)):
            if isinstance(failure, SolverError) and where:
                failure = NumericalError(f"{failure}", **where)
            failure.collective = True
            raise failure
        if mode == "reject":
            self._restore(system, None, report)
            report.kept_iteration = 0
            report.rejected = True
            self.rejections += 1
        report.failed = True
        prefix = {"reject": "IIPS call rejected: ", "warn": "IIPS call kept despite: "}.get(mode, "")
        report.message = f"{prefix}{failure}"  # (best: the failure says what was kept)
        self.failures += 1

    def max_shift(self, system) -> float:
        """Largest displacement of the last call (collective)."""
        return largest_shift(system)


def largest_shift(system) -> float:
    """Largest displacement of the owned particles in the field SHIFT_FIELD, over all ranks (collective)."""
    s = system.particles.owned(SHIFT_FIELD.name)
    return allreduce_max(system.comm, float(np.sqrt((s * s).sum(axis=1)).max()) if len(s) else 0.0)


def pre_procedure(spec, comm, system, iips=None, surface=None):
    """The static pre-procedure (thesis Algorithms 2-4, line 2): `spec.pre_newton` IIPS iterations with no
    threshold, whatever the run's shifting method, so that every method starts from the same distribution.
    From a perturbed lattice (`initial.sigma_over_dx`) it gives a relaxed distribution that is not a lattice.
    `iips`: the run's own ImplicitShifting, which then keeps its beta threshold; without it a temporary one
    is used and freed. Returns Linf(grad C) after it and the iterations it took (with iips.backtrack, possibly
    fewer than pre_newton), or (None, 0) when `spec.pre_newton` is 0. Collective."""
    if spec.pre_newton == 0:
        return None, 0

    def label(info):  # a failure's place: "[pre-procedure, iteration k]" (check_escaped, IIPS's errors)
        system.where = {"stage": "pre-procedure", "iteration": info["newton"] + 1}

    label({"newton": 0})
    # a temporary pre-procedure sets no beta threshold: the run's shifting is not IIPS, and reads no iips.beta
    temporary = None if iips is not None else ImplicitShifting(replace(spec, beta=0.0), comm, surface=surface)
    # the fields a temporary one adds, which the run's method never updates: left, every snapshot showed
    # the pre-procedure's last shift as the run's (Procedure C, an audit)
    added = [f.name for f in (SHIFT_FIELD, GUESS_FIELD) if f.name not in system.particles] if temporary else []
    try:
        shifting = iips or temporary
        return shifting.prepare(system, on_iteration=label), shifting.pre_iterations
    finally:
        system.where = {}
        if temporary is not None:
            temporary.destroy()
            for name in added:
                system.particles.remove_field(name)
