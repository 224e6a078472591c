"""Particle migration and halo exchange, periodic images included (every function communicates).

A halo pattern is built once per neighbour-list rebuild: for every rank r and every periodic image
shift s (s_a in {-1, 0, 1} along periodic axes), the owned particles whose image x + s L lies within
`radius` of rank r's box are sent to r (a rank sends periodic images to itself too). The pattern is
then reused to refresh any chosen set of fields; positions travel with their image shift.
"""

import itertools
from dataclasses import dataclass

import numpy as np

from psph.compute.neighbours import image_rows
from psph.parallel.comm import allreduce_max, alltoallv_fields, exchange_counts


@dataclass
class HaloPattern:
    """Which owned rows go to which rank (and with what periodic shift) to form the halos."""

    send_index: np.ndarray  # (n_send,) owned rows, grouped by destination rank
    send_shift: np.ndarray  # (n_send, dim) displacement added to positions
    send_counts: np.ndarray  # (nranks,)
    recv_counts: np.ndarray  # (nranks,)

    @property
    def n_halo(self) -> int:
        return int(self.recv_counts.sum())


def _image_shifts(domain):
    axes = [(-1, 0, 1) if p else (0,) for p in domain.periodic]
    return [np.array(s, dtype=np.float64) * domain.length for s in itertools.product(*axes)]


def build_halo_pattern(comm, pos_owned: np.ndarray, decomposition, domain, radius: float) -> HaloPattern:
    """Pattern sending every owned particle (or periodic image) within `radius` of another box. Collective."""
    shifts = np.array(_image_shifts(domain)).reshape(-1, domain.dim)
    box_lo, box_hi = (np.array([box[k] for box in decomposition.boxes], dtype=np.float64) for k in (0, 1))
    skip = np.zeros((len(box_lo), len(shifts)), dtype=np.bool_)
    skip[comm.rank] = ~shifts.any(axis=1)  # a rank's own particles, unshifted, are no halo of its own
    rows, which, counts = image_rows(np.ascontiguousarray(pos_owned), box_lo, box_hi, shifts, skip, radius)
    return HaloPattern(send_index=rows, send_shift=shifts[which], send_counts=counts,
                       recv_counts=exchange_counts(comm, counts))


def halo_exchange(comm, particles, pattern: HaloPattern, names) -> None:
    """Refresh the halo rows of fields `names` from their owners using `pattern`. Collective.

    The halo rows must already exist (attach_halo); positions receive their periodic image shift.
    """
    lo = particles.n_owned
    received = halo_copies(comm, pattern, {name: particles[name][:lo] for name in names}, shifted=("position",))
    for name, rows in received.items():
        particles[name][lo:] = rows


def attach_halo(comm, particles, pattern: HaloPattern, names) -> None:
    """Create the halo rows for `pattern` and fill fields `names` (others are zero). Collective."""
    received = halo_copies(comm, pattern, {name: particles.owned(name) for name in names}, shifted=("position",))
    particles.set_halo(received, pattern.n_halo)


def migrate(comm, particles, dest: np.ndarray) -> None:
    """Move owned particles (all fields) to the ranks `dest` gives; drops the halo. Collective. Where no
    particle changes rank (most rebuilds: IIPS rebuilds about once per Newton iteration in a violent flow)
    only the halo is dropped, without the exchange of every field."""
    counts = np.bincount(dest, minlength=comm.size).astype(np.int64)
    if allreduce_max(comm, int(counts[comm.rank] != particles.n_owned)) == 0:
        particles.set_owned({name: particles.owned(name) for name in particles.names})
        return
    order = np.argsort(dest, kind="stable")
    recv_counts = exchange_counts(comm, counts)
    particles.set_owned(alltoallv_fields(comm, {name: particles.owned(name)[order] for name in particles.names},
                                         counts, recv_counts))


def halo_copies(comm, pattern: HaloPattern, arrays: dict, shifted=()) -> dict:
    """Send the rows of owned `arrays` through `pattern` without touching any ParticleSet; arrays named in
    `shifted` are positions and receive the periodic image shift. Returns the received rows. Collective."""
    data = {}
    for name, arr in arrays.items():
        data[name] = arr[pattern.send_index]
        if name in shifted:
            data[name] = data[name] + pattern.send_shift
    return alltoallv_fields(comm, data, pattern.send_counts, pattern.recv_counts)
