"""Named phases: wall time accumulated per phase and, once PETSc is up, a PETSc log event per phase
(so `-log_view` shows psph's halo exchange, neighbour search, IIPS assembly and solve)."""

import time
from collections import defaultdict
from contextlib import contextmanager

_totals = defaultdict(float)
_exclusive = defaultdict(float)
_counts = defaultdict(int)
_events = {}
_children = []  # per open phase: time spent so far in the phases nested inside it


def _event(name):
    from psph.solvers import petsc

    if not petsc.is_initialized():
        return None
    if name not in _events:
        _events[name] = petsc.petsc().Log.Event(f"psph:{name}")
    return _events[name]


@contextmanager
def phase(name: str):
    """Time the enclosed block as phase `name` (also a PETSc log event when PETSc is initialised)."""
    event = _event(name)
    if event is not None:
        event.begin()
    start = time.perf_counter()
    _children.append(0.0)
    try:
        yield
    finally:
        elapsed = time.perf_counter() - start
        _totals[name] += elapsed
        _exclusive[name] += elapsed - _children.pop()
        if _children:
            _children[-1] += elapsed
        _counts[name] += 1
        if event is not None:
            event.end()


def totals() -> dict:
    """{phase: (seconds, calls)} accumulated in this process so far (nested phases count in their parents
    too)."""
    return {k: (_totals[k], _counts[k]) for k in _totals}


def exclusive() -> dict:
    """{phase: seconds} outside the phases nested in it: parts that do not overlap."""
    return dict(_exclusive)


def reset() -> None:
    _totals.clear()
    _exclusive.clear()
    _counts.clear()


def memory() -> tuple:
    """(resident, peak resident) bytes of this process: Linux's VmRSS and VmHWM, else (where /proc is
    missing) the peak from getrusage for both, or 0 where neither is available."""
    try:
        with open("/proc/self/status") as status:
            fields = dict(line.split(":", 1) for line in status if line.startswith(("VmRSS", "VmHWM")))
        return tuple(1024 * int(fields[k].split()[0]) for k in ("VmRSS", "VmHWM"))
    except (OSError, KeyError, ValueError):
        try:
            import resource
        except ImportError:  # neither (Windows): unknown
            return 0, 0
        import sys

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * (1 if sys.platform == "darwin" else 1024)
        return peak, peak

