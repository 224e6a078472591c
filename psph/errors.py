"""Typed errors. Each carries a one-line message meant for the user (the CLI prints it, no traceback)."""


def point(position) -> str:
    """A position as a message names it: (0.25, 1)."""
    return "(" + ", ".join(f"{float(v):.6g}" for v in position) + ")"


class PsphError(Exception):
    """Base class: an error psph diagnoses and reports in one line."""

    exit_code = 1


class SceneError(PsphError):
    """Invalid scene: names the key path of the offending value."""

    exit_code = 2

    def __init__(self, key: str, message: str):
        self.key = key
        super().__init__(f"{key}: {message}" if key else message)


class UsageError(PsphError):
    """Invalid command line (bad --set, missing file, output directory in use)."""

    exit_code = 2


class NumericalError(PsphError):
    """The computation broke down (NaN, escaped particle, stalled iteration): stop and diagnose (exit 3)."""

    exit_code = 3

    def __init__(self, message: str, *, step=None, time=None, gid=None, position=None, iteration=None, stage=None):
        self.step, self.time, self.gid, self.position, self.iteration = step, time, gid, position, iteration
        self.stage = stage
        where = [] if stage is None else [stage]  # a part of the run before its steps ("pre-procedure")
        if step is not None:
            where.append(f"step {step}")
        if iteration is not None:  # a static run's (its snapshots' step)
            where.append(f"iteration {iteration}")
        if time is not None:
            where.append(f"t = {time:.6g}")
        if gid is not None:
            where.append(f"particle gid {gid}")
        if position is not None:
            finite = all(abs(float(v)) < float("inf") for v in position)  # NaN fails the comparison too
            where.append(("at " if finite else "at a non-finite position ") + point(position))
        super().__init__(message + (" [" + ", ".join(where) + "]" if where else ""))


class SolverError(NumericalError):
    """A PETSc linear solve did not converge: carries the converged reason and iteration count."""

    def __init__(self, solver: str, reason: str, iterations: int, **where):
        self.solver, self.reason, self.iterations = solver, reason, iterations
        super().__init__(f"{solver} linear solve diverged: {reason} after {iterations} iterations", **where)


def is_collective(err) -> bool:
    """Whether every rank raises `err` at the same point: a PsphError that says so (`collective`), or by
    default a scene or usage error (found in what every rank reads). Any other error may be one rank's."""
    return isinstance(err, PsphError) and getattr(err, "collective", isinstance(err, (SceneError, UsageError)))


# what a NumericalError says about where it happened (its keyword arguments)
WHERE = ("step", "time", "gid", "position", "iteration", "stage")


def rebuild_error(cls, message: str, where=None) -> PsphError:
    """An instance of `cls` carrying `message` as is, and the attributes `where` (a NumericalError's WHERE),
    to re-raise another rank's error."""
    err = cls.__new__(cls)
    Exception.__init__(err, message)
    for name, value in (where or {}).items():
        setattr(err, name, value)
    return err
