"""Cell-list neighbour search against brute force, including clustered and coincident particles."""

import numpy as np
import pytest

from psph.compute.neighbours import build_neighbour_lists, image_rows, max_displacement, spatial_order


def brute_force(pos, n_rows, radius):
    d2 = ((pos[:n_rows, None, :] - pos[None, :, :]) ** 2).sum(axis=2)
    return [set(np.flatnonzero(d2[i] < radius * radius)) - {i} for i in range(n_rows)]


def clouds(dim, rng):
    n = {1: 300, 2: 600, 3: 800}[dim]
    uniform = rng.uniform(0.0, 1.0, (n, dim))
    # clustered and coincident: the lists outgrow the search's first guess of their length (its buffer grows)
    clustered = np.concatenate([rng.normal(c, 0.02, (n // 4, dim)) for c in rng.uniform(0, 1, (4, dim))])
    coincident = np.repeat(rng.uniform(0.0, 1.0, (n // 3, dim)), 3, axis=0)
    # a lattice of spacing 0.025 puts pairs exactly at the radius 0.05 and on the cells' edges
    side = round(n ** (1 / dim))
    lattice = np.stack(np.meshgrid(*[0.025 * np.arange(side)] * dim, indexing="ij"), -1).reshape(-1, dim)
    return {"uniform": uniform, "clustered": clustered, "coincident": coincident, "lattice": lattice}


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_lists_equal_brute_force(dim):
    rng = np.random.default_rng(dim)
    for label, pos in clouds(dim, rng).items():
        for radius in (0.05, 0.13):
            n_rows = len(pos) * 2 // 3  # the rest play the halo
            ptr, idx = build_neighbour_lists(pos, n_rows, radius)
            expect = brute_force(pos, n_rows, radius)
            got = [set(idx[ptr[i]:ptr[i + 1]]) for i in range(n_rows)]
            assert got == expect, label
            assert all(len(idx[ptr[i]:ptr[i + 1]]) == len(got[i]) for i in range(n_rows)), "duplicates"
            assert idx.dtype == np.int32  # half the memory of int64 (docs/results.md, "Memory")


def test_coincident_particles_are_neighbours():
    pos = np.array([[0.5, 0.5], [0.5, 0.5], [0.9, 0.9]])
    ptr, idx = build_neighbour_lists(pos, 3, 0.1)
    assert list(idx[ptr[0]:ptr[1]]) == [1] and list(idx[ptr[1]:ptr[2]]) == [0] and ptr[3] == ptr[2]


def test_empty_and_isolated():
    ptr, idx = build_neighbour_lists(np.zeros((0, 2)), 0, 0.1)
    assert ptr.tolist() == [0] and idx.size == 0
    ptr, idx = build_neighbour_lists(np.array([[0.0, 0.0], [5.0, 5.0]]), 2, 0.1)
    assert ptr.tolist() == [0, 0, 0]


def test_sparse_cloud_caps_cell_count():
    """Two far-apart clusters would need ~1e12 cells of the list radius; the grid coarsens instead."""
    pos = np.array([[0.0, 0.0], [1e6, 1e6], [1e-3, 0.0]])
    ptr, idx = build_neighbour_lists(pos, 3, 0.01)
    assert [set(idx[ptr[i]:ptr[i + 1]]) for i in range(3)] == [{2}, set(), {0}]


def test_a_runaway_particle_coarsens_the_grid_instead_of_overflowing():
    """A 3-D extent of 1e6 list radii would need ~1e19 cells of half the radius (beyond int64)."""
    pos = np.array([[0.0, 0.0, 0.0], [1.7e6, 1.7e6, 1.7e6], [0.5, 0.0, 0.0]])
    ptr, idx = build_neighbour_lists(pos, 3, 1.0)
    assert [set(idx[ptr[i]:ptr[i + 1]]) for i in range(3)] == [{2}, set(), {0}]


def test_spatial_order_is_a_permutation_grouping_cells():
    rng = np.random.default_rng(0)
    pos = rng.uniform(0, 1, (500, 2))
    order = spatial_order(pos, 0.1)
    assert sorted(order) == list(range(500))
    cells = np.floor(pos[order] / 0.1).astype(int)  # the global grid's cells, [k 0.1, (k + 1) 0.1)
    key = cells[:, 0] * 1000 + cells[:, 1]
    assert np.all(np.diff(key) >= 0)


def test_max_displacement():
    a = np.zeros((3, 2))
    b = np.array([[0.0, 0.0], [3.0, 4.0], [1.0, 0.0]])
    assert max_displacement(b, a, 3) == 5.0
    assert max_displacement(b, a, 1) == 0.0


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_image_rows_equal_brute_force(dim):
    """Halo rows (psph.parallel.halo) for boxes that tile a periodic box, one reaching +-inf, with particles on
    box faces and within the radius of the domain's edges: the same rows in the same order as testing every
    image against every box."""
    rng = np.random.default_rng(10 + dim)
    pos = np.concatenate([rng.uniform(0.0, 1.0, (400, dim)), np.full((5, dim), 0.5), np.zeros((3, dim))])
    pos[:20, 0] = rng.uniform(0.0, 0.03, 20)  # near the lower edge: their +1 images are halos
    box_lo = np.array([[0.0] * dim, [0.5] + [0.0] * (dim - 1), [0.0] * (dim - 1) + [0.7]])
    box_hi = np.array([[0.5] + [np.inf] * (dim - 1), [1.0] * dim, [0.5] + [1.0] * (dim - 1)])
    axes = [(-1.0, 0.0, 1.0)] * dim
    shifts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, dim)
    skip = np.zeros((3, len(shifts)), dtype=np.bool_)
    skip[1] = ~shifts.any(axis=1)
    radius = 0.05
    rows, which, counts = image_rows(pos, box_lo, box_hi, shifts, skip, radius)
    expect_rows, expect_which, expect_counts = [], [], []
    for r in range(3):
        for s, shift in enumerate(shifts):
            if skip[r, s]:
                continue
            x = pos + shift
            near = np.flatnonzero(np.all((x > box_lo[r] - radius) & (x < box_hi[r] + radius), axis=1))
            expect_rows += list(near)
            expect_which += [s] * len(near)
        expect_counts.append(len(expect_rows) - sum(expect_counts))
    assert rows.tolist() == expect_rows and which.tolist() == expect_which
    assert counts.tolist() == expect_counts
    assert np.any(which != np.flatnonzero(~shifts.any(axis=1))[0]), "some periodic image is a halo"


@pytest.mark.parametrize("scale", [1e-120, 1.0, 1e120])
def test_lists_at_any_scale_of_the_coordinates(scale):
    """The first guess of the lists' length is made in cells, so no coordinate scale overflows it."""
    pos = np.random.default_rng(3).uniform(0.0, 1.0, (300, 3)) * scale
    ptr, idx = build_neighbour_lists(pos, 200, 0.2 * scale)
    expect = brute_force(pos, 200, 0.2 * scale)
    assert [set(idx[ptr[i]:ptr[i + 1]]) for i in range(200)] == expect


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_a_rows_order_is_the_same_on_any_rank(dim):
    """Rows list their neighbours by the cells of space (a grid aligned with x = k size, not with each rank's
    own particles) and, within a cell, by gid: a particle's row holds the same gids in the same order whether
    the rank holds all the particles, in any order, or only some, with the rest as its halo (so a particle's
    sums agree between rank counts to the last bit: tests/drivers/test_fluid_parallel.py)."""
    rng = np.random.default_rng(dim)
    n = {1: 200, 2: 600, 3: 1500}[dim]
    pos = rng.uniform(0.3, 1.7, (n, dim))
    gid = rng.permutation(n).astype(np.int64)
    radius = 0.35
    ptr, idx = build_neighbour_lists(pos, n, radius, gid)
    rows = {int(gid[i]): gid[idx[ptr[i]:ptr[i + 1]]].tolist() for i in range(n)}
    for trial in range(3):  # a "rank": the points left of a cut, in a shuffled order, and a halo beyond it
        cut = 0.7 + 0.3 * trial
        owned = rng.permutation(np.flatnonzero(pos[:, 0] < cut))
        halo = rng.permutation(np.flatnonzero((pos[:, 0] >= cut) & (pos[:, 0] < cut + radius)))
        local = np.concatenate([owned, halo])
        p, i_ = build_neighbour_lists(pos[local], len(owned), radius, gid[local])
        for k, g in enumerate(gid[owned]):
            assert gid[local][i_[p[k]:p[k + 1]]].tolist() == rows[int(g)]
