"""What every driver shares: it is a context manager that frees its PETSc objects and communicators."""

from psph.errors import is_collective


class Driver:
    """A driver owns a Simulation (`self.sim`) and the solvers it builds. Leaving a `with` block over it
    closes it: its shifting's PETSc objects are destroyed and its communicators freed at that point on every
    rank, whether the run ended, stopped or failed on every rank. Left to Python, an error's traceback keeps
    them in a reference cycle that each rank's collector frees at its own moment; the next PETSc object made
    on a communicator whose last one has gone on some ranks only then hangs (psph.solvers.petsc.petsc_comm).
    An error raised on some ranks only is left alone: the command line aborts every rank then, and a close
    would wait for the others in a collective."""

    sim = None
    closed = False

    def shifting_methods(self) -> tuple:
        """The shifting methods this driver built (their destroy frees their PETSc objects)."""
        return ()

    def close(self) -> None:
        """Destroy the shifting methods' PETSc objects, then free the simulation's communicators (its output
        stays). Collective; a second call does nothing."""
        if self.closed:
            return
        self.closed = True
        for method in self.shifting_methods():
            method.destroy()
        self.sim.close()

    def __enter__(self):
        return self

    def __exit__(self, kind, error, traceback):
        if error is None or is_collective(error):
            self.close()
        return False
