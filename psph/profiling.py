"""Named phases: wall time accumulated per phase and, once PETSc is up, a PETSc log event per phase
(so `-log_view` shows psph's halo exchange, neighbour search, IIPS assembly and solve)."""

import time
from collections import defaultdict

_totals = defaultdict(float)
_exclusive = defaultdict(float)
_counts = defaultdict(int)
_events = {}
_children = []  # per open phase: time spent so far in the phases nested inside it


def _event(name):
    """The PETSc log event of phase `name` (made on first use), or None before PETSc is initialised."""
    event = _events.get(name)
    if event is not None:
        return event
    from psph.solvers import petsc

    if not petsc.is_initialized():
        return None
    event = _events[name] = petsc.petsc().Log.Event(f"psph:{name}")
    return event


class phase:
    """Time the enclosed block (`with phase(name):`) as phase `name`, also a PETSc log event when PETSc is
    initialised. A class with slots, not a generator context manager: a run enters 60-80 phases a step, at
    1.5-1.9 us each against 4-4.75 (a speed audit: 2% of a small dam break)."""
    __slots__ = ("name", "event", "start")

    def __init__(self, name: str):
        self.name = name

    def __enter__(self):
        self.event = event = _event(self.name)
        if event is not None:
            event.begin()
        _children.append(0.0)
        self.start = time.perf_counter()

    def __exit__(self, *exc):
        elapsed = time.perf_counter() - self.start
        name = self.name
        _totals[name] += elapsed
        _exclusive[name] += elapsed - _children.pop()
        if _children:
            _children[-1] += elapsed
        _counts[name] += 1
        if self.event is not None:
            self.event.end()
        return False


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

