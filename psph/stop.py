"""Stopping a run on request, with its state saved.

`psph run` catches SIGTERM (`kill`, a batch system's time limit), SIGINT (Ctrl-C) and SIGUSR1 (what
OpenMPI's mpiexec passes on to every rank; with Slurm, `#SBATCH --signal=B:USR1@120`). The first one
only raises a flag: the run ends the step in progress, writes a checkpoint, the history and a snapshot
of that state (Simulation.snapshot_once; a continuation writes its next snapshot over it), and exits
with 128 + the signal's number and one line saying how to continue. A second signal stops at once, with
nothing saved past the last checkpoint.

The flag is checked collectively (a max-reduction over the ranks, once per step), so every rank stops
after the same step even when the signal reached them at different moments.
"""

import os
import signal
import threading

from psph.errors import PsphError

SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGUSR1)

_state = {"installed": False, "signum": 0, "rank": 0, "previous": {}, "after": "step with a checkpoint"}


class Stopped(PsphError):
    """A run stopped on request; the exit code is 128 + the signal's number. Raised on every rank."""

    collective = True

    def __init__(self, signum: int, message: str):
        self.signum = signum
        self.exit_code = 128 + signum
        super().__init__(f"stopped by {signal.Signals(signum).name}: {message}")


class ForcedStop(KeyboardInterrupt):
    """A second signal: stop at once."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


def _handler(signum, frame):
    if _state["signum"]:
        raise ForcedStop(signum)
    _state["signum"] = signum
    if _state["rank"] == 0:  # os.write: print() may be in the middle of a progress line
        os.write(2, f"\npsph: {signal.Signals(signum).name} received: stopping after this {_state['after']} "
                    "(send it again to stop at once)\n".encode())


def install(comm, after="step with a checkpoint") -> None:
    """Catch SIGNALS in this process (main thread only; elsewhere, nothing). Call on every rank. `after`: what
    the first signal's line says the run stops after (a static run: "iteration with a snapshot")."""
    if threading.current_thread() is not threading.main_thread():
        return
    _state.update(installed=True, signum=0, rank=comm.rank, after=after)
    _state["previous"] = {sig: signal.signal(sig, _handler) for sig in SIGNALS}


def uninstall() -> None:
    """Give the signals back to the handlers `install` replaced."""
    if not _state["installed"]:
        return
    _state.update(installed=False, signum=0)
    for sig, previous in _state["previous"].items():
        signal.signal(sig, signal.SIG_DFL if previous is None else previous)


def requested(comm) -> int:
    """The signal some rank was asked to stop by (0 if none, or if `install` did not run). Collective
    when installed on every rank (as `psph run` does)."""
    if not _state["installed"]:
        return 0
    return int(comm.allreduce(_state["signum"], op=_max()))


def checkpoint_message(step: int, t: float, path, ranks: int = 1, snapshot=None) -> str:
    """What a time-dependent run says when it stops: where its state is (the checkpoint `path` and the
    `snapshot` to look at) and how to continue (on as many ranks)."""
    launch = f"mpiexec -n {ranks} " if ranks > 1 else ""
    shown = f" and {snapshot}" if snapshot is not None else ""
    return (f"state at step {step}, t = {t:.6g} saved in {path}{shown}; continue with: {launch}psph run "
            f"--restart {path}")


def _max():
    from mpi4py import MPI

    return MPI.MAX
