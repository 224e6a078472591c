"""What every shifting method offers to the drivers."""

from dataclasses import dataclass, field

import numpy as np

from psph.diagnostics import fluid_mask, grad_c, norms
from psph.parallel.comm import global_first
from psph.profiling import phase


@dataclass
class ShiftReport:
    """Outcome of one correction call (one time step, or one static run)."""

    iterations: int = 0
    linear_iterations: int = 0
    L2_grad_c: float = np.nan
    Linf_grad_c: float = np.nan
    rejected: bool = False
    failed: bool = False
    message: str = ""
    history: list = field(default_factory=list)
    # the iteration whose state a failed call kept (on_stall "best": its lowest Linf(grad C); "reject": 0, the
    # start); None: the last
    kept_iteration: int | None = None


def measure(system, volume="volume", mask=None):
    """(grad C of the owned particles, L2(grad C), Linf(grad C)) over the free (fluid) particles, or the owned
    rows of `mask`; C is weighted by the field `volume` (diagnostics.grad_c). Collective."""
    with phase("grad_c"):
        grad = grad_c(system, volume)
        l2, linf = norms(system.comm, grad, fluid_mask(system) if mask is None else mask, system.kernel.h)
    return grad, l2, linf


def steepest(system, vectors, rows) -> dict:
    """The owned `rows`' particle of largest |vector| (grad C, a shifting velocity) over all ranks (the lowest
    gid of equals; a non-finite value counts as the largest), as a failure's place: {"gid", "position"}, or
    {} where no rank has a row. Collective."""
    p = system.particles
    local = None
    if rows.size:
        size = np.nan_to_num(np.linalg.norm(vectors[rows], axis=1), nan=np.inf)
        top = np.flatnonzero(size == size.max())
        k = rows[top[np.argmin(p.owned("gid")[rows[top]])]]  # (the lowest gid of this rank's equals)
        local = (float(size.max()), int(p.owned("gid")[k]), p.owned("position")[k].copy())
    first = global_first(system.comm, local)
    return {} if first is None else {"gid": first[1], "position": first[2]}


class Shifting:
    """What every shifting method has: a static pre-procedure (prepare; returns Linf(grad C) after it, or
    None) and destroy (free its PETSc objects now; collective). Neither does anything here."""

    def prepare(self, system, on_iteration=None):
        return None

    def destroy(self) -> None:
        pass


class NoShifting(Shifting):
    """shifting.method = "none": particles are never moved by a shifting law."""

    name = "none"

    def correct(self, system, on_iteration=None, iterations=None, **where) -> ShiftReport:
        """No shifting: only measure the distribution. Collective."""
        _, l2, linf = measure(system)
        return ShiftReport(L2_grad_c=l2, Linf_grad_c=linf)
