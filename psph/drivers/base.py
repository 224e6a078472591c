"""What every driver shares: it is a context manager that frees its PETSc objects and communicators."""

import math
import sys
from contextlib import contextmanager

from psph.errors import is_collective


def resumed_state(restart, scene):
    """The driver's state in a restart's checkpoint (io.checkpoint.read_checkpoint's), or None. A restart may
    change output.every (cli.RESTART_KEYS): its snapshots then follow the new period, from its first multiple
    after the checkpoint's time (none before the end for 0); with the saved period, the saved next time, so
    that the snapshots fall on the steps of the run without the restart."""
    if restart is None:
        return None
    state, every = restart[0]["driver"], scene.output.every
    if restart[0]["scene"]["output"]["every"] != every:
        t = state["time"]
        state["next_output"] = (math.floor(t / every + 1e-9) + 1) * every if every > 0 else math.inf
    return state


class Driver:
    """A driver owns a Simulation (`self.sim`) and the shifting methods it builds (`self.shifting`, a fluid
    driver's `self.iips`). Leaving a `with` block over it closes it: the shifting methods' PETSc objects are
    destroyed and the communicators freed at that point on every rank, whether the run ended, stopped or
    failed on every rank; a constructor that fails on every rank closes what it had built. Left to Python,
    an error's traceback keeps them in a reference cycle that each rank's collector frees at its own moment;
    the next PETSc object made on a communicator whose last one has gone on some ranks only then hangs
    (psph.solvers.petsc.petsc_comm). An error raised on some ranks only is left alone: the command line
    aborts every rank then, and a close would wait for the others in a collective."""

    sim = None
    closed = False

    def shifting_methods(self) -> tuple:
        """The shifting methods built so far (their destroy frees their PETSc objects)."""
        return tuple(m for m in (getattr(self, "shifting", None), getattr(self, "iips", None)) if m is not None)

    def close(self) -> None:
        """Destroy the shifting methods' PETSc objects, then free the simulation's communicators (its output
        stays). Collective; a second call does nothing."""
        if self.closed:
            return
        self.closed = True
        for method in self.shifting_methods():
            method.destroy()
        if self.sim is not None:
            self.sim.close()

    def _close_after(self, error) -> None:
        """Close after `error` if every rank raised it. A failure of the close itself is reported in a line and
        dropped: the run's own error is what the user must see."""
        if not is_collective(error):
            return
        try:
            self.close()
        except Exception as failure:
            print(f"psph: warning: freeing the run's solvers after the error failed: {failure}", file=sys.stderr,
                  flush=True)

    @contextmanager
    def closing_on_failure(self):
        """For a constructor, after its Simulation: an error raised on every rank closes what was built."""
        try:
            yield
        except BaseException as error:
            self._close_after(error)
            raise

    def __enter__(self):
        return self

    def __exit__(self, kind, error, traceback):
        if error is None:
            self.close()
        else:
            self._close_after(error)
        return False
