"""Decomposition, migration, halo and every SPH sum: identical on 1, 2 and 3 ranks (compared by gid).

Run on several rank counts by run_scripts/test.sh (`mpiexec -n N python -m pytest --with-mpi -m mpi`).
"""

import numpy as np
import pytest
from mpi4py import MPI

from psph.compute import sums
from psph.diagnostics import distribution_report
from psph.domain import Domain
from psph.parallel.decomposition import recursive_bisection
from psph.simulation import build_system
from tests.conftest import gather_by_gid, periodic_scene

pytestmark = pytest.mark.mpi


def all_sums(system):
    """Every SPH sum of the foundation on the owned particles, keyed by name."""
    p, k = system.particles, system.kernel
    pos, vol, ptr, idx, kp = p["position"], p["volume"], system.nbr_ptr, system.nbr_idx, k.params
    n, d = p.n_owned, p.dim
    phi = np.sin(2 * np.pi * pos[:, 0]) + (np.cos(2 * np.pi * pos[:, 1]) if d > 1 else 0.0)
    u = np.stack([np.sin(2 * np.pi * pos[:, (a + 1) % d]) for a in range(d)], axis=1)
    out = {"C": np.zeros(n), "grad_C": np.zeros((n, d)), "grad": np.zeros((n, d)), "grad_diff": np.zeros((n, d)),
           "div": np.zeros(n), "lap": np.zeros(n), "visc": np.zeros((n, d)), "M": np.zeros((n, d, d)),
           "lambda_min": np.zeros(n)}
    sums.concentration(pos, vol, ptr, idx, kp, out["C"])
    sums.grad_concentration(pos, vol, ptr, idx, kp, out["grad_C"])
    sums.gradient(pos, vol, ptr, idx, kp, phi, out["grad"])
    sums.gradient_difference(pos, vol, ptr, idx, kp, phi, out["grad_diff"])
    sums.divergence(pos, vol, ptr, idx, kp, u, out["div"])
    sums.laplacian_morris(pos, vol, ptr, idx, kp, phi, out["lap"])
    sums.viscous_pi(pos, vol, ptr, idx, kp, u, out["visc"])
    sums.renormalisation_matrix(pos, vol, ptr, idx, kp, out["M"])
    sums.smallest_eigenvalue(out["M"], out["lambda_min"])
    lmat = np.zeros((n, d, d))
    sums.invert_renormalisation(out["M"], out["lambda_min"], 1e-6, lmat)
    out["grad_renorm"] = out["grad_diff"].copy()
    sums.apply_renormalisation(lmat, out["grad_renorm"])
    return out


@pytest.mark.parametrize("dim,n", [(1, 64), (2, 24), (3, 10)])
def test_every_sum_matches_serial_by_gid(comm, dim, n):
    scene = periodic_scene(dim=dim, n=n, sigma=0.2, kernel="wendland_c6")
    parallel = build_system(scene, comm)
    serial = build_system(scene, MPI.COMM_SELF)
    assert parallel.n_global == serial.n_owned == n**dim
    got = all_sums(parallel)
    ref = all_sums(serial)
    order = np.argsort(serial.particles.owned("gid"))
    for name in got:
        gids, values = gather_by_gid(comm, parallel.particles.owned("gid"), got[name])
        assert np.array_equal(gids, np.arange(n**dim))
        expect = ref[name][order]
        scale = max(np.abs(expect).max(), 1.0)
        assert np.abs(values - expect).max() < 1e-12 * scale, name


def test_halo_gives_exactly_the_periodic_neighbours(comm):
    scene = periodic_scene(dim=2, n=20, sigma=0.3)
    s = build_system(scene, comm)
    p = s.particles
    all_gid, all_pos = gather_by_gid(comm, p.owned("gid"), p.owned("position"))
    box = Domain((0.0, 0.0), (1.0, 1.0), (True, True))
    support = s.kernel.support
    for i in range(p.n_owned):
        nbrs = p["gid"][s.nbr_idx[s.nbr_ptr[i]:s.nbr_ptr[i + 1]]]
        dist = np.linalg.norm(p["position"][s.nbr_idx[s.nbr_ptr[i]:s.nbr_ptr[i + 1]]] - p["position"][i], axis=1)
        mine = set(nbrs[dist < support])
        d_all = np.linalg.norm(box.minimum_image(all_pos - p["position"][i]), axis=1)
        expect = set(all_gid[(d_all < support) & (all_gid != p["gid"][i])])
        assert mine == expect


def test_migration_carries_fields_and_balances(comm):
    scene = periodic_scene(dim=2, n=30, sigma=0.25)
    s = build_system(scene, comm)
    p = s.particles
    gids = np.concatenate(comm.allgather(p.owned("gid")))
    assert np.array_equal(np.sort(gids), np.arange(900))  # nobody lost, nobody duplicated
    counts = comm.allgather(p.n_owned)
    assert max(counts) - min(counts) <= 31  # at most one lattice column off the median
    assert np.allclose(p.owned("volume"), (1 / 30) ** 2)
    b_lo, b_hi = s.decomposition.boxes[comm.rank]
    assert np.all((p.owned("position") >= b_lo) & (p.owned("position") <= b_hi))


def test_migrate_without_moves_keeps_the_rows_and_with_moves_carries_them(comm):
    """No particle changing rank (the shortcut, no exchange): the owned rows stay as they were, in order, and
    the halo goes. Every particle sent to the next rank: each arrives there with its fields."""
    from psph.parallel.halo import migrate

    s = build_system(periodic_scene(dim=2, n=12, sigma=0.1), comm)
    p = s.particles
    before = p.owned_arrays()
    assert p.n_halo > 0
    migrate(comm, p, np.full(p.n_owned, comm.rank))
    assert p.n_halo == 0 and all(np.array_equal(p.owned(k), v) for k, v in before.items())
    incoming = comm.sendrecv(before, dest=(comm.rank + 1) % comm.size, source=(comm.rank - 1) % comm.size)
    migrate(comm, p, np.full(p.n_owned, (comm.rank + 1) % comm.size))
    assert all(np.array_equal(p.owned(k), v) for k, v in incoming.items())


def test_fields_travel_in_one_message_as_they_would_one_by_one(comm):
    """alltoallv_fields packs rows of several dtypes and shapes (int8, int64, float, (d,), (d, d)) side by
    side as bytes: each arrives as alltoallv sends it alone, also where a rank sends or receives nothing."""
    from psph.parallel.comm import alltoallv, alltoallv_fields, exchange_counts

    rng = np.random.default_rng(comm.rank)
    counts = np.array([0 if (comm.rank + r) % 3 == 1 else 2 + r + comm.rank for r in range(comm.size)], np.int64)
    n = int(counts.sum())
    arrays = {"kind": rng.integers(0, 6, n).astype(np.int8), "gid": rng.integers(0, 10**12, n),
              "position": rng.random((n, 2)), "matrix": rng.random((n, 2, 2))}
    recv = exchange_counts(comm, counts)
    together = alltoallv_fields(comm, arrays, counts, recv)
    for name, a in arrays.items():
        alone = alltoallv(comm, a, counts, recv)
        assert together[name].dtype == a.dtype and np.array_equal(together[name], alone), name


def test_alltoallv_delivers_each_row_and_counts_in_rows(comm):
    """Every row reaches its rank whole and in order, and MPI is given counts and displacements in rows (of
    a type one row long), not in bytes: in bytes they passed MPI's C int from about 10 M rows of a
    migration (a parallel audit: OverflowError, the run aborted; 9 M rows of 256 bytes, 2.3 GB from one
    rank to another, now arrive, measured by hand)."""
    from psph.parallel.comm import alltoallv, exchange_counts

    counts = np.array([1 + comm.rank + 2 * r for r in range(comm.size)], np.int64)
    rows = np.concatenate([[(comm.rank, r, k, 0.5) for k in range(c)] for r, c in enumerate(counts)])
    recv = exchange_counts(comm, counts)
    seen = []

    class Recorder:  # the communicator, noting what alltoallv hands MPI
        def __getattr__(self, name):
            return getattr(comm, name)

        def Alltoallv(self, send, receive):
            seen.append((list(send[1][0]), list(receive[1][0]), send[2].Get_size()))
            return comm.Alltoallv(send, receive)

    out = alltoallv(Recorder(), rows, counts, recv)
    expected = np.concatenate([[(r, comm.rank, k, 0.5) for k in range(c)] for r, c in enumerate(recv)])
    assert np.array_equal(out, expected)
    if comm.size > 1:
        assert seen == [(list(counts), list(recv), rows.shape[1] * rows.itemsize)]


def test_update_refreshes_halo_then_rebuilds(comm):
    """Small moves reuse the lists; larger ones trigger a rebuild; sums stay rank-independent."""
    scene = periodic_scene(dim=2, n=24, sigma=0.1)
    s = build_system(scene, comm)
    serial = build_system(scene, MPI.COMM_SELF)

    def move(system, amount):
        pos = system.particles.owned("position")
        gid = system.particles.owned("gid")
        pos[:, 0] += amount * np.sin(gid.astype(float))
        pos[:, 1] += amount * np.cos(gid * 0.7)
        return system.update()

    small = 0.2 * s.skin
    assert move(s, small) is False and move(serial, small) is False
    got, ref = all_sums(s), all_sums(serial)
    order = np.argsort(serial.particles.owned("gid"))
    for name in ("grad_C", "lap"):
        assert np.allclose(gather_by_gid(comm, s.particles.owned("gid"), got[name])[1], ref[name][order],
                           rtol=0, atol=1e-12 * np.abs(ref[name]).max())
    assert move(s, 2.0 * s.skin) is True and move(serial, 2.0 * s.skin) is True
    got, ref = all_sums(s), all_sums(serial)
    order = np.argsort(serial.particles.owned("gid"))
    assert np.allclose(gather_by_gid(comm, s.particles.owned("gid"), got["grad_C"])[1], ref["grad_C"][order],
                       rtol=0, atol=1e-12 * np.abs(ref["grad_C"]).max())


def test_rebalance_on_demand(comm):
    """Crowd the particles into one corner: the next rebuild rebalances the counts."""
    s = build_system(periodic_scene(dim=2, n=30), comm)
    pos = s.particles.owned("position")
    pos *= 0.3
    s.rebuild()
    counts = comm.allgather(s.n_owned)
    assert max(counts) - min(counts) <= 31
    s.rebuild(rebalance=False)
    assert comm.allgather(s.n_owned) == counts


def test_a_rank_beyond_the_lists_index_range_stops_every_rank(comm, monkeypatch):
    """A rank holding more particles than the lists' indices address stops all ranks with one message
    before the search, not that rank alone inside a collective rebuild."""
    from psph.compute import neighbours
    from psph.errors import UsageError, is_collective

    s = build_system(periodic_scene(dim=2, n=20), comm)
    s.particles.owned("position")[:] *= 0.3  # crowded into a corner, kept on their ranks: uneven counts
    s.rebuild(rebalance=False)
    counts = comm.allgather(s.particles.n_local)
    assert comm.size == 1 or sorted(counts)[-1] > sorted(counts)[-2], counts  # one rank is the fullest
    monkeypatch.setattr(neighbours, "INDEX_LIMIT", max(counts) - 1)  # exceeded on the fullest rank only
    with pytest.raises(UsageError, match=f"a rank holds {max(counts)} particles with its halo") as caught:
        s.rebuild(rebalance=False)
    assert is_collective(caught.value)


@pytest.mark.mpi(min_size=3)
def test_tiny_system_leaves_ranks_empty(comm):
    """Two particles on three ranks or more: the ranks without particles take part, and the distribution's
    report is the serial one."""
    from psph.compute.smoothing import make_kernel
    from psph.particles import ParticleSet
    from psph.system import ParticleSystem

    def tiny(on):
        p = ParticleSet(2)
        mine = np.array([0, 1]) if on.rank == 0 else np.zeros(0, dtype=np.int64)
        p.set_owned({"gid": mine, "position": np.array([[0.5, 0.5], [0.52, 0.5]])[: len(mine)],
                     "kind": np.zeros(len(mine), np.int8), "volume": np.full(len(mine), 1e-3)})
        domain = Domain((0.0, 0.0), (1.0, 1.0), (False, False))
        return ParticleSystem(on, domain, make_kernel("wendland_c2", 2, 0.02), p)

    s = tiny(comm)
    assert s.n_global == 2 and comm.allreduce(int(s.particles.n_owned == 0)) == comm.size - 2
    report = distribution_report(s, 0.5)
    serial = distribution_report(tiny(MPI.COMM_SELF), 0.5)
    assert report["L2_grad_c"] > 0.0
    assert report == pytest.approx(serial, rel=1e-12, abs=0.0)


@pytest.mark.mpi(min_size=3)
def test_a_snapshot_with_fewer_particles_than_ranks_is_written(comm, tmp_path):
    """Two particles on three ranks give one rank an empty block of the snapshot: h5py skipped its part of the
    collective write, and the other ranks waited in theirs for ever (a hang, found by an audit)."""
    import h5py

    from psph.io.snapshots import SnapshotWriter
    from psph.particles import ParticleSet

    p = ParticleSet(2)
    mine = np.array([comm.rank]) if comm.rank < 2 else np.zeros(0, dtype=np.int64)  # 1 or 2 particles
    p.set_owned({"gid": mine, "position": np.array([[0.25 + 0.5 * comm.rank, 0.5]])[: len(mine)],
                 "kind": np.zeros(len(mine), np.int8), "volume": np.full(len(mine), 1e-3)})
    out = comm.bcast(tmp_path, root=0)
    path = SnapshotWriter(comm, out, Domain((0.0, 0.0), (1.0, 1.0), (False, False))).write(p, step=0, time=0.0)
    if comm.rank == 0:
        with h5py.File(path) as f:
            n = min(comm.size, 2)
            assert list(f["particles/gid"][()]) == list(range(n))
            assert np.allclose(f["particles/position"][()], [[0.25 + 0.5 * k, 0.5] for k in range(n)])


def test_rcb_splits_weights_evenly(comm):
    rng = np.random.default_rng(comm.rank)
    pos = rng.uniform(0.0, 1.0, (1000 + 100 * comm.rank, 2))
    box = Domain((0.0, 0.0), (1.0, 1.0), (True, False))
    dec = recursive_bisection(comm, pos, box)
    owner = dec.rank_of(pos)
    counts = np.bincount(owner, minlength=comm.size)
    total = comm.allreduce(counts)
    assert total.max() - total.min() <= 1
    for r, (lo, hi) in enumerate(dec.boxes):
        assert np.all((pos[owner == r] >= lo) & (pos[owner == r] < hi))
        assert lo[1] == -np.inf or lo[1] > 0.0  # outer faces of the non-periodic axis are open
        assert hi[1] == np.inf or hi[1] < 1.0
        assert 0.0 <= lo[0] < hi[0] <= 1.0  # the periodic axis stays inside the box


def test_rcb_cuts_a_thin_layer_across_its_length(comm):
    """A layer 0.1 deep at the bottom of a tank 4 tall is cut across its length (x), not into slabs along the
    box's longest side (y) whose boundary every wave crosses; the counts stay even."""
    rng = np.random.default_rng(comm.rank)
    pos = rng.uniform(0.0, 1.0, (800, 2)) * [1.0, 0.1]
    dec = recursive_bisection(comm, pos, Domain((0.0, 0.0), (1.0, 4.0), (False, False)))
    assert all(s.axis == 0 for s in dec.splits)
    counts = comm.allreduce(np.bincount(dec.rank_of(pos), minlength=comm.size))
    assert counts.max() - counts.min() <= 1


@pytest.mark.parametrize("empty_rank", [False, True])
def test_gid_blocks_are_contiguous_and_sorted_with_sparse_gids(comm, empty_rank):
    """Gids with gaps (an outlet removed some), dealt at random over the ranks (one possibly empty): the blocks,
    in rank order, are the global ascending-gid order, and each row's data travels with its gid."""
    from psph.parallel.ordering import to_gid_blocks

    rng = np.random.default_rng(7)
    every = np.sort(rng.choice(10_000, size=500, replace=False)) + 3
    holder = rng.integers(0, comm.size, size=len(every))
    if empty_rank:
        holder[holder == comm.size - 1] = 0
    mine = rng.permutation(every[holder == comm.rank])
    start, total, out = to_gid_blocks(comm, mine, {"twice": 2.0 * mine, "pair": np.stack([mine, -mine], axis=1)})
    assert total == len(every)
    blocks = comm.allgather((start, out["twice"] / 2.0, out["pair"]))
    assert [b[0] for b in blocks] == list(np.cumsum([0] + [len(b[1]) for b in blocks])[:-1])
    assert np.array_equal(np.concatenate([b[1] for b in blocks]), every)
    assert np.array_equal(np.concatenate([b[2] for b in blocks]), np.stack([every, -every], axis=1))


def test_a_file_rank_0_reads_for_all_gives_every_rank_its_content_or_its_error(tmp_path):
    """parallel.comm.on_root (a style audit: the scene file was read by every rank, and one that could not
    read it stopped alone, exit 2, while the others waited in the next collective): rank 0 reads, every rank
    gets the result, and rank 0's failure is every rank's, with its type and words."""
    from psph.errors import SceneError
    from psph.parallel.comm import on_root

    comm = MPI.COMM_WORLD
    assert on_root(comm, lambda: {"rank": comm.rank}) == {"rank": 0}

    def fails_on_rank_0():
        if comm.rank == 0:
            raise SceneError("packing.start", "no file nothing.h5")
        return "never asked"

    with pytest.raises(SceneError, match="packing.start: no file nothing.h5"):
        on_root(comm, fails_on_rank_0)
    # another exception is raised as rank 0's, of its type, on every rank (a review: rank 0 raised the
    # FileNotFoundError, the others a PsphError naming it, and a library catching OSError stranded them)
    with pytest.raises(FileNotFoundError, match="No such file or directory") as info:
        on_root(comm, lambda: open(tmp_path / "no-such-file").read())
    assert info.value.collective
    with pytest.raises(SystemExit):  # not an Exception: the others waited in the broadcast for ever (a review)
        on_root(comm, lambda: exit(3))
    # an unpicklable result is rank 0's error, every rank's (the others waited in the broadcast for ever); one
    # rank passes it on as it is
    if comm.size > 1:
        with pytest.raises(Exception, match="pickle"):
            on_root(comm, lambda: (lambda: None))
    big = np.arange(3 * 2**20, dtype=np.float64)  # 24 MiB in chunks of 8 MiB
    import psph.parallel.comm as comm_module

    chunk, comm_module.BROADCAST_CHUNK = comm_module.BROADCAST_CHUNK, 2**23
    try:
        assert np.array_equal(on_root(comm, lambda: big if comm.rank == 0 else None), big)
    finally:
        comm_module.BROADCAST_CHUNK = chunk


def test_the_particle_a_message_names_is_the_largest_key_then_the_lowest_gid_on_every_rank(comm):
    """parallel.comm.global_first: the largest key over the ranks, ties to the lowest gid, whatever rank
    holds it (a style audit: check_escaped and the fluid driver's check named the lowest rank's first)."""
    from psph.parallel.comm import global_first

    size = comm.size
    # keys 0, 1, 0, ...: the odd ranks' largest; gids fall with the rank
    assert global_first(comm, (comm.rank % 2, 100 - comm.rank, comm.rank))[2] == (0 if size == 1 else
                                                                                 max(range(1, size, 2)))
    assert global_first(comm, (0.0, 100 - comm.rank, comm.rank))[2] == size - 1  # all equal: the lowest gid
    assert global_first(comm, (0.0, 7, comm.rank) if comm.rank == size - 1 else None)[2] == size - 1
    assert global_first(comm, None) is None
