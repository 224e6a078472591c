"""Cell-list neighbour search against brute force, including clustered and coincident particles."""

import numpy as np
import pytest

from psph.compute.neighbours import build_neighbour_lists, max_displacement, spatial_order


def brute_force(pos, n_rows, radius):
    d2 = ((pos[:n_rows, None, :] - pos[None, :, :]) ** 2).sum(axis=2)
    return [set(np.flatnonzero(d2[i] < radius * radius)) - {i} for i in range(n_rows)]


def clouds(dim, rng):
    n = {1: 300, 2: 600, 3: 800}[dim]
    uniform = rng.uniform(0.0, 1.0, (n, dim))
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
    cells = np.floor((pos[order] - pos.min(axis=0)) / 0.1).astype(int)
    key = cells[:, 0] * 1000 + cells[:, 1]
    assert np.all(np.diff(key) >= 0)


def test_max_displacement():
    a = np.zeros((3, 2))
    b = np.array([[0.0, 0.0], [3.0, 4.0], [1.0, 0.0]])
    assert max_displacement(b, a, 3) == 5.0
    assert max_displacement(b, a, 1) == 0.0
