"""Load every hot compute kernel before a run's timed work.

numba compiles (first run on a machine: about a minute per dimension, on one core) or loads from its on-disk
cache (later runs: 2-3 ms) each kernel on its first call. Calling them once on a tiny particle cloud at
start-up keeps that cost out of the time loops (it stays in the run's total wall time); a one-iteration IIPS
call takes 20-40 ms (tests/compute/test_warmup.py checks that a run of each kind loads nothing more).
"""

import numpy as np

from psph.compute import (
    csr,
    eos,
    field_update,
    fluid,
    free_surface,
    iips,
    neighbours,
    random,
    riemann,
    shift_velocity,
    sums,
    walls,
)
from psph.compute.smoothing import make_kernel


def _lattice(dim: int, spacing: float) -> np.ndarray:
    """The 3^dim points of a tiny lattice, C-contiguous as the particles' positions are."""
    grid = np.stack(np.meshgrid(*[np.arange(3.0)] * dim, indexing="ij"), axis=-1).reshape(3 ** dim, dim)
    return np.ascontiguousarray(grid * spacing)


PARTS = frozenset({"fluid", "delta_ale", "riemann", "walls", "ghost_walls", "open", "free_surface", "shifting", "iips",
                   "assembled", "field_update"})


def warm_up(dim: int, kernel_name: str, parts=PARTS) -> None:
    """Call the hot kernels once with the argument types a run of dimension `dim` uses: those every run
    calls (the neighbour lists, grad C, the diagnostics' sums), and those of the `parts` (PARTS) its scene
    has (psph.simulation.warm_up_parts), so that a run compiles only what it calls (a cold start of the
    static case took 27.5 s with every kernel, 23.9 s with its own; Taylor-Green's, which calls most of
    them, 39 s either way)."""
    n = 3 ** dim
    pos = _lattice(dim, 0.5)
    vol = np.full(n, 0.25 ** dim)
    gid = np.arange(n, dtype=np.int64)
    kernel = make_kernel(kernel_name, dim, 0.5)
    kp = kernel.params
    kernel.value(np.zeros(1))
    ptr, idx = neighbours.build_neighbour_lists(pos, n, 2.0)
    neighbours.spatial_order(pos, 2.0)
    box = np.array([[0.0] * dim])
    neighbours.image_rows(pos, box, box + 1.0, np.zeros((1, dim)), np.zeros((1, 1), dtype=np.bool_), 0.1)
    neighbours.max_displacement(pos, pos, n)
    neighbours.coincident_rows(pos, gid, ptr, idx, 1e-9)
    random.gaussian_by_gid(0, gid, dim)
    scalar, vector, tensor = np.zeros(n), np.zeros((n, dim)), np.zeros((n, dim, dim))
    field = np.ones(n)
    sums.grad_concentration(pos, vol, ptr, idx, kp, vector)
    sums.gradient(pos, vol, ptr, idx, kp, field, vector)  # L2(d f/dx), the static runs' accuracy
    sums.nearest_distance(pos, ptr, idx, np.zeros(n, dtype=np.int8), np.zeros(n, dtype=np.int8), scalar)
    if "shifting" in parts:  # the explicit laws (shifting.velocity_shift)
        shift_velocity.limit_magnitude(vector, field, vector.copy())
    if "free_surface" in parts:  # the detection (boundaries.free_surface)
        flag, fluid_rows = np.zeros(n, dtype=np.int8), np.ones(n, dtype=np.bool_)
        sums.renormalisation_and_grad_c(pos, vol, ptr, idx, kp, tensor, vector)
        sums.smallest_eigenvalue(tensor, scalar)
        free_surface.outward_normals(tensor, scalar, vector, 0.5, 1e-3, vector.copy())
        free_surface.scan_surface(pos, fluid_rows, fluid_rows, scalar, vector, ptr, idx, 0.5, 0.2, 0.75, flag)
        free_surface.mark_region(pos, fluid_rows, ptr, idx, 1.0, flag)
        free_surface.region_normals(pos, flag, ptr, idx, kp, vector)
        free_surface.restrict_shift(flag, scalar, vector, 0.4, vector.copy())
    row = gid.copy()
    if "assembled" in parts:  # the assembled IIPS matrix (solvers.aij)
        indptr, indices, slot = iips.iips_structure(row, ptr, idx, dim)
        iips.iips_values(pos, vol, row, ptr, idx, kp, slot, np.zeros(len(indices)), np.zeros(0))
        half = (len(indptr) - 1) // 2  # the matrix split over two ranks: its diagonal and off-diagonal blocks
        di, dj, oi, oj = csr.split_csr(indptr, indices, 0, half)
        where = np.empty_like(slot)  # row pointers as solvers.aij reads them from PETSc (int64)
        csr.split_positions(indptr, indices, 0, half, di.astype(np.int64), oi.astype(np.int64), slot, where)
        if dim > 1:  # the BAIJ codes (solvers.aij)
            bptr, bcols = csr.block_pattern(indptr, indices, dim)
            csr.block_codes(indptr, dim, bptr, np.arange(len(bcols), dtype=np.int32), slot, where)
    if "iips" in parts:  # the matrix-free operator (shifting.iips_operator)
        col = row.astype(np.int32)
        bptr, bcol = np.empty(n + 1, dtype=np.int64), np.empty(len(idx), dtype=np.int32)
        hess = np.empty((len(idx), dim * (dim + 1) // 2))
        iips.iips_pairs(pos, col, ptr, idx, kp, kernel.support, bptr, bcol, hess)
        iips.iips_product(1.0, bptr, bcol, hess, vector, vector.copy())
    kind = np.zeros(n, dtype=np.int8)
    if "field_update" in parts:  # after an IIPS call of a flow (shifting.field_update)
        field_update.nfts_increments(pos, vol, field, vector, vector, kind, np.zeros((1, dim)), ptr, idx, kp,
                                     scalar.copy(), scalar.copy(), vector.copy())
        cptr, cidx = neighbours.build_cross_lists(pos, pos, 1.0)
        old = np.ones((n, 3 + dim))  # the volumes (a strided column) and the fields, as MovingLeastSquares has them
        for order in (1, 2):
            field_update.mls_interpolate(pos, pos, old[:, 0], np.ascontiguousarray(old[:, 1:]), cptr, cidx, kp,
                                         order, np.zeros((n, 2 + dim)))
    if "fluid" not in parts:
        return
    eos.elementwise(eos.PRESSURE, field, 1.0, 1.0, True)  # the scheme's equation of state (schemes.eos)
    for directional in (False, True):  # the viscous step limit (schemes.viscous_limit)
        sums.largest_kernel_factor_sum(pos, vol, ptr, idx, kp, np.arange(n), directional, np.zeros((0, dim, dim)))
    fluid.fluid_momentum_totals(kind, field, vector, vector, True, np.empty(2 * dim + 1))
    fluid.add_uniform_acceleration(kind, field, np.zeros(dim), True, vector.copy())
    pairs = fluid.PairCache()
    fluid.renormalised_gradient(pos, vol, field, ptr, idx, kp, kind, False, vector, pairs)
    if "shifting" in parts:  # a law on the corrected grad C takes it from the gradient's pass
        fluid.renormalised_gradient(pos, vol, field, ptr, idx, kp, kind, False, vector, pairs,
                                    grad_c=(0.2, 4.0, 1.0, vector.copy()))
    if "riemann" in parts:  # the Riemann SPH-ALE scheme (schemes.riemann_ale)
        riemann.velocity_gradient(pos, vol, vector, pairs, tensor)
        riemann.riemann_ale_rhs(pos, vol, field, field, vector, vector, vector, tensor, pairs, 1.0, 1.0, True, 0.1,
                                False, np.zeros(dim), scalar, scalar.copy(), vector.copy(), limited=True,
                                low_dissipation=False)
    if "delta_ale" in parts:  # the delta-ALE schemes (schemes.delta_ale)
        fluid.delta_ale_rhs(pos, vol, field, field, vector, vector, field, vector, pairs, kp, 1.0, 0.1, 0.1, 0.01,
                            np.zeros(dim), 0, True, True, kind, False, scalar, scalar.copy(), vector.copy())
    if "open" in parts:  # an outflow buffer, an inflow buffer's extrapolated density (boundaries.open)
        sums.shepard_from_fluid(pos, vol, kind, gid.copy(), ptr, idx, kp, field.copy(), vector.copy(), 0.1, 1.0)
    if dim == 2 and "ghost_walls" in parts:  # the fixed ghost particles' images (boundaries.clone)
        ghosts = {"axis": np.array([1]), "coord": np.array([0.0]), "sign": np.array([1.0])}
        rows = gid.copy()
        images = walls.ghost_images(pos, kind, rows, ghosts, ptr, idx, kernel.support)
        walls.ghost_rhs(pos, vol, field, vector, vector, scalar, rows, *images, ghosts["axis"], ghosts["coord"],
                        np.zeros((1, 2)), True, kp, 1.0, 1.0, False, 0.1, True, np.zeros(2), 0, True,
                        np.zeros(n, dtype=np.int8), scalar.copy(), vector.copy())
        for mat in (walls.NO_MATRIX, tensor.copy()):
            walls.ghost_grad_c(pos, vol, rows, *images, ghosts["axis"], ghosts["coord"], kp, 0.0, 1.0, 1.0,
                               vector.copy(), mat)
    if dim == 2 and "walls" in parts:  # the clone walls (boundaries.clone), on no row
        rows = walls.near_wall_rows(kind, ptr, idx)
        bodies = 1
        walls.clone_rhs(pos, vol, field, vector, vector, scalar, kind, np.zeros(n, dtype=np.int64), vector, scalar,
                        vector, vector, rows, np.zeros((0, bodies, 2)), np.zeros((0, bodies)),
                        np.zeros(bodies, dtype=np.bool_), ptr, idx, kp, 1.0, 1.0, False, 0.1, True, np.zeros(2),
                        0.1, 0, True, np.zeros(n, dtype=np.int8), np.zeros(n, dtype=np.int8), np.zeros((bodies, 2)),
                        scalar.copy(), vector.copy(), np.zeros((bodies, 2, 2)), np.zeros((bodies, 2)), np.zeros((n, 2)))
        walls.off_walls(np.zeros((1, 2, 2)), np.zeros(1, dtype=np.int64), vector.copy())
        fixed_nodes = pos.copy()  # (a fixed body's nodes, and so its k-d tree's data, are read-only: Body.nodes)
        fixed_nodes.flags.writeable = False
        for nodes in (pos, fixed_nodes):
            walls.contour_distance(nodes, np.zeros((n, 2), dtype=np.int64), np.zeros(n, dtype=np.int64), pos)
        walls.clone_viscous_weight(pos, vol, kind, np.zeros(n, dtype=np.int64), vector, scalar, rows,
                                   np.zeros((0, bodies)), np.zeros(bodies, dtype=np.bool_), ptr, idx, kp, 0.1,
                                   True, np.zeros((0, 2, 2)))


def warm_up_more(dim: int) -> None:
    """Kernels of less common paths that a run does not load ahead (the corrected grad C of the explicit
    shifting laws, Neuhauser's correction): compiled once before the test suite (run_scripts/test.sh), whose
    processes would otherwise each compile them at once."""
    n = 3 ** dim
    pos = _lattice(dim, 1.0)
    vol, field, vector = np.ones(n), np.zeros(n), np.zeros((n, dim))
    kp = make_kernel("wendland_c6", dim, 1.0).params
    ptr, idx = neighbours.build_neighbour_lists(pos, n, 2.0)
    shift_velocity.corrected_grad_c(pos, vol, ptr, idx, kp, 0.2, 4.0, 1.0, vector)
    shift_velocity.neuhauser_acceleration(pos, vol, vector.copy(), field, ptr, idx, kp, 10.0, 0.1, vector)


if __name__ == "__main__":  # python -m psph.compute.warmup DIM ...: compile (or load) the kernels before tests
    import sys

    for dim in sys.argv[1:] or ["1", "2", "3"]:
        warm_up(int(dim), "wendland_c6")  # the kernel is a value inside the arguments: one compile serves all
        warm_up_more(int(dim))
