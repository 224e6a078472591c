"""The distributed particle system: particles, decomposition, halo and neighbour lists on one rank.

Collective methods (every rank must call them together) say so. Between rebuilds the halo pattern and
the neighbour lists are reused; `update()` after a position change either refreshes the halo positions
or, once some particle has moved more than half the skin, rebuilds everything (wrap, rebalance,
migrate, sort, halo, lists).
"""

import numpy as np

from psph.compute import neighbours
from psph.compute.neighbours import build_neighbour_lists, coincident_rows, max_displacement, spatial_order
from psph.compute.random import gaussian_by_gid
from psph.errors import NumericalError, UsageError
from psph.parallel.comm import allreduce_max, allreduce_sum, exclusive_scan, global_first
from psph.parallel.decomposition import recursive_bisection
from psph.parallel.halo import attach_halo, build_halo_pattern, halo_exchange, migrate
from psph.profiling import phase

BASE_HALO_FIELDS = ("position", "gid", "kind", "volume")


class ListsExpired(Exception):
    """Some owned particle moved more than half the skin since the last rebuild while the particle order had
    to stay fixed (inside a time step): the lists may miss pairs. Carries the largest displacement."""

    def __init__(self, moved, gid, position):
        self.moved, self.gid, self.position = moved, gid, position
        super().__init__(f"a particle moved {moved:.3g} since the neighbour lists were built")


class ParticleSystem:
    """Owned + halo particles of one rank with the data every SPH sum needs.

    comm: communicator (duplicated here; the library never picks the world communicator itself);
    domain: Domain;
    kernel: compute.smoothing.Kernel; particles: this rank's ParticleSet (any distribution);
    skin: Verlet skin as a fraction of the kernel support; decomposition: boxes to start from (a restart
    on as many ranks), else the particles are balanced by recursive bisection.
    """

    def __init__(self, comm, domain, kernel, particles, *, skin=0.1, rebalance_threshold=1.1,
                 halo_fields=BASE_HALO_FIELDS, decomposition=None):
        """Build the neighbour lists of `particles` distributed over comm (duplicated). Collective."""
        self.comm = comm.Dup()
        self.domain = domain
        self.kernel = kernel
        self.particles = particles
        self.skin = skin * kernel.support
        self.list_radius = kernel.support + self.skin
        self.rebalance_threshold = rebalance_threshold
        self.halo_fields = list(dict.fromkeys(halo_fields))
        self.decomposition = decomposition
        self.pattern = None
        self.nbr_ptr = np.zeros(1, dtype=np.int64)
        self.nbr_idx = np.zeros(0, dtype=np.int32)
        self.rebuilds = 0
        self._reference = None
        # separate_coincident's last search: (its lists, the local positions then, the closest pair's distance)
        self._coincident_search = None
        self.where = {}  # the driver's step and time, for the reports of check_escaped
        self.rebuild(rebalance=decomposition is None)

    def close(self) -> None:
        """Free this system's communicator (the particles stay readable). Collective; the PETSc objects made
        on it must have been destroyed first."""
        from psph.solvers.petsc import release_comm

        release_comm(self.comm)

    # ----------------------------------------------------------------- layout
    @property
    def n_owned(self) -> int:
        return self.particles.n_owned

    @property
    def n_global(self) -> int:
        """Total particle count (collective)."""
        return int(allreduce_sum(self.comm, self.n_owned))

    def add_halo_field(self, name: str) -> None:
        """Carry field `name` in the halo from now on (filled at the next exchange)."""
        if name not in self.halo_fields:
            self.particles[name]  # raises if unknown
            self.halo_fields.append(name)

    # ------------------------------------------------------------- rebuilding
    def rebuild(self, rebalance=None) -> None:
        """Wrap, (re)balance, migrate, sort, build halo and neighbour lists. Collective."""
        with phase("rebuild"):
            self._rebuild(rebalance)

    def _rebuild(self, rebalance):
        p = self.particles
        pos = p.owned("position")
        self.check_escaped()
        self.domain.wrap(pos)
        if self.decomposition is None:
            rebalance = True
        dest = None
        if not rebalance:
            dest = self.decomposition.rank_of(pos)
            if rebalance is None:  # rebalance when the current boxes would hold too uneven counts
                counts = allreduce_sum(self.comm, np.bincount(dest, minlength=self.comm.size))
                rebalance = counts.max() / max(counts.mean(), 1.0) > self.rebalance_threshold
        if rebalance:
            self.decomposition = recursive_bisection(self.comm, pos, self.domain)
            dest = self.decomposition.rank_of(pos)
        migrate(self.comm, p, dest)
        p.permute_owned(spatial_order(p.owned("position"), self.list_radius))
        with phase("halo_exchange"):
            self.pattern = build_halo_pattern(self.comm, p.owned("position"), self.decomposition, self.domain,
                                              self.list_radius)
            attach_halo(self.comm, p, self.pattern, self.halo_fields)
        self._check_index_range()
        with phase("neighbour_search"):
            self.nbr_ptr, self.nbr_idx = build_neighbour_lists(p["position"], p.n_owned, self.list_radius,
                                                               p["gid"])
        self._reference = p.owned("position").copy()
        self.rebuilds += 1

    def _check_index_range(self) -> None:
        """Stop every rank if some rank holds, halo included, more particles than the lists' 32-bit indices
        address (`compute.neighbours.INDEX_LIMIT`), before the search would raise on that rank alone. Collective."""
        largest = int(allreduce_max(self.comm, np.array([self.particles.n_local]))[0])
        if largest > neighbours.INDEX_LIMIT:
            error = UsageError(f"a rank holds {largest} particles with its halo, more than the neighbour lists' 32-bit "
                               f"indices address ({neighbours.INDEX_LIMIT}): run on more ranks")
            error.collective = True
            raise error

    def update(self) -> bool:
        """Call after owned positions changed: refresh halo positions or rebuild. Collective.

        Returns True when the lists were rebuilt (particle order and halo changed).
        """
        p = self.particles
        moved = max_displacement(p["position"], self._reference, p.n_owned)
        if 2.0 * allreduce_max(self.comm, moved) > self.skin:
            self.rebuild()
            return True
        with phase("halo_exchange"):
            halo_exchange(self.comm, p, self.pattern, ["position"])
        return False

    def check_lists(self) -> None:
        """Raise ListsExpired on every rank if some owned particle moved more than half the skin since the
        last rebuild (the lists may then miss pairs); for moves that cannot rebuild, such as the stages of a
        time step. A non-finite position stops all ranks instead (check_escaped). Collective."""
        p = self.particles
        moved = max_displacement(p["position"], self._reference, p.n_owned)
        worst = allreduce_max(self.comm, moved)
        if worst == np.inf:  # a non-finite position (a stage's NaN reached the walls' node search: an audit)
            self.check_escaped()
        if 2.0 * worst > self.skin:
            gid, position = None, None
            if moved == worst and p.n_owned:
                k = int(np.argmax(((p.owned("position") - self._reference) ** 2).sum(axis=1)))
                gid, position = int(p.owned("gid")[k]), p.owned("position")[k].copy()
            raise ListsExpired(worst, gid, position)

    def prepare_step(self, reach: float) -> bool:
        """Rebuild now if a step moving particles by up to `reach` could take one past half the skin, so
        that the step's stages need only refresh halo positions. Collective; True if rebuilt."""
        p = self.particles
        moved = max_displacement(p["position"], self._reference, p.n_owned)
        if 2.0 * (allreduce_max(self.comm, moved) + reach) > self.skin:
            self.rebuild()
            return True
        return False

    def refresh(self, names) -> None:
        """Refresh halo copies of fields `names` from their owners. Collective."""
        for name in names:
            self.add_halo_field(name)
        with phase("halo_exchange"):
            halo_exchange(self.comm, self.particles, self.pattern, list(names))

    def check_escaped(self) -> None:
        """Stop all ranks if an owned particle left the box along a non-periodic axis or has a non-finite
        position (which no neighbour search can place), naming the counts over all ranks, the particle of
        lowest gid among those with a non-finite position, else among those that left (whatever the number of
        ranks: a style audit found the lowest rank's first named), and the driver's step and time
        (self.where). Collective."""
        pos, gids = self.particles.owned("position"), self.particles.owned("gid")
        broken = ~np.isfinite(pos).all(axis=1)
        outside = self.domain.outside(pos) & ~broken
        counts = allreduce_sum(self.comm, np.array([np.count_nonzero(outside), np.count_nonzero(broken)]))
        if not counts.any():
            return
        rows = np.flatnonzero(broken if counts[1] else outside)
        k = rows[np.argmin(gids[rows])] if len(rows) else None
        first = global_first(self.comm, (0, int(gids[k]), None if counts[1] else pos[k].copy())
                             if k is not None else None)  # (a non-finite position is no place)
        if counts[1]:
            what = (f"{counts[1]} particle(s) with a non-finite position"
                    + (f" and {counts[0]} left the domain" if counts[0] else ""))
        else:
            what = f"{counts[0]} particle(s) left the domain"
        error = NumericalError(what, gid=first[1], position=first[2], **self.where)
        error.collective = True  # (every rank raises it)
        raise error

    def separate_coincident(self, tolerance: float, offset: float) -> int:
        """Nudge one particle of every pair closer than `tolerance` by `offset` (a direction drawn from its
        gid, so rank-independent). Kernel gradients vanish at r = 0, so no shifting law can split an
        exactly coincident pair by itself. Returns the global number of particles moved. Collective."""
        p = self.particles
        rows = self._coincident_rows(tolerance)
        moved = int(allreduce_sum(self.comm, len(rows)))
        if moved:
            direction = gaussian_by_gid(0x5EED, p.owned("gid")[rows], p.dim)
            direction /= np.linalg.norm(direction, axis=1)[:, None]
            p.owned("position")[rows] += offset * direction
            self.update()
        return moved

    def _coincident_rows(self, tolerance: float) -> np.ndarray:
        """compute.neighbours.coincident_rows of the current positions, without the pass over every pair (a
        speed audit: 3.5% of the cavity) while none of the pairs it measured last can have come within
        `tolerance`: with the same lists (new arrays at every rebuild, and after any change of rows) and every
        local row, halo included, at most `moved` from where it was then, a pair then r apart is now at least
        r - 2 moved apart. The search is skipped if r - 2 moved > 2 tolerance (the factor 2 covers the round-off
        of the distances, ~1e-16 of the coordinates, many orders below it), so the rows found are the same.
        Not collective."""
        p = self.particles
        pos = p["position"]
        last = self._coincident_search
        if last is not None and last[0] is self.nbr_ptr and last[1] is self.nbr_idx and last[2].shape == pos.shape:
            moved = max_displacement(pos, last[2], len(pos))  # (inf for a non-finite position: no skip)
            if last[3] - 2.0 * moved > 2.0 * tolerance:
                return np.zeros(0, dtype=np.int64)
        rows, closest2 = coincident_rows(pos, p["gid"], self.nbr_ptr, self.nbr_idx, tolerance)
        self._coincident_search = (self.nbr_ptr, self.nbr_idx, pos.copy(), np.sqrt(closest2))
        return rows

    # ------------------------------------------------------------- numbering
    def global_rows(self, free_mask: np.ndarray) -> tuple:
        """Global numbers of the owned particles in `free_mask` (others -1), from an exclusive scan.

        Returns (rows for all local particles incl. halo, first row of this rank, owned free count).
        Collective (exchanges the numbers to the halo through field 'row').
        """
        from psph.particles import FieldSpec

        n_free = int(np.count_nonzero(free_mask))
        first = exclusive_scan(self.comm, n_free)
        p = self.particles
        p.add_field(FieldSpec("row", (), np.int64), fill=-1)
        row = p["row"]
        row[:] = -1
        owned_rows = row[: p.n_owned]
        owned_rows[free_mask] = first + np.arange(n_free, dtype=np.int64)
        self.refresh(["row"])
        return p["row"], first, n_free
