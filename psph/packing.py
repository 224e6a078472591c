"""Particle packing before a flow (Colagrossi, Bouscasse, Antuono and Marrone 2012, seed 002 section 2).

A lattice cut by a curved or sloping boundary leaves grad Gamma_i = sum_j grad W_ij V_j of order 1/h near
it, and the SPH pressure gradient there is wrong by 2 p_i grad Gamma_i (seed 002 eq. 1.12-1.13): the flow
starts by resettling its particles. The packing moves the fluid particles beforehand under the damped
fictitious dynamics of seed 002 eq. 2.16,
    du_i/dt = -beta grad Gamma_i - zeta u_i,   dr_i/dt = u_i,   Gamma_i = sum_j W_ij V0,
whose undamped part is Lagrangian with potential (beta / 2) sum_i Gamma_i over the fluid plus the fixed
particles' share (eq. 2.18), so the damping drives it to a stable state of small |grad Gamma|.

Fixed particles close the fluid domain (seed 002 section 2: "the free surface has to be treated as a solid
boundary"): the walls' solid particles (clone walls), and FRAME particles laid outside each free surface for
the packing only, in layers dx apart parallel to it over one kernel support (rings around a drop, lattice
rows beyond a fill region's side), removed afterwards. The frame weighs V0, as the fluid does (seed 002
eq. 2.14, 2.18); the walls' solid particles keep their own volumes (their fitted cells, within 3% of V0),
the ones the flow uses, and the force is the exact gradient of eq. 2.18's potential with them.

Constants (seed 002 eq. 2.15-2.17): beta = 2 p0 / rho0 only scales the fictitious time, so psph takes
beta = 1 (velocities in units of sqrt(beta)); V0 = V_tot / N, the drop's area pi R^2 or the fill's volume
(fluid_volume) over the particle count; dt = cfl V0^(1/d) / sqrt(beta) (eq. 2.17), at most cfl h / (2 sqrt(beta)):
the fictitious dynamics' fastest oscillation scales with 1 / h, and with Wendland C6 the paper's step
diverges below h = 2 dx (at h/dx = 1.3 within 33 iterations, measured; the cap changes nothing from
h = 2 dx up); zeta = alpha sqrt(beta) / V0^(1/d). Integration: symplectic Euler with the damping taken
implicitly,
    u <- (u - dt beta grad Gamma) / (1 + zeta dt),   r <- r + dt u.
Stop once T = sum_i |u_i|^2 / 2 over the fluid (the specific kinetic energy, eq. 2.18) falls below
packing.tolerance x beta, or after packing.iterations iterations; the particles start at rest, so T counts
only from one damping time 1 / zeta on (before, where the forces would leave it below the tolerance too:
T at the terminal speeds |grad Gamma| / zeta, a lattice start at rest).
"""

import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from psph.boundaries.bodies import bounds
from psph.compute.neighbours import closest_pair
from psph.diagnostics import fluid_mask, grad_c, norms
from psph.errors import NumericalError
from psph.parallel.comm import allreduce_max, allreduce_sum, global_first, raise_if_any
from psph.particles import FieldSpec, Kind

VELOCITY = FieldSpec("packing_velocity", ("d",))
RECORD_EVERY = 10  # iterations between rows of the packing history


def frame_positions(scene) -> np.ndarray:
    """Positions of the frame particles that close the scene's free surfaces during the packing: rings at
    R + (k + 1/2) dx around a drop, or the lattice points beyond the fill region's sides (inside the walls),
    over one kernel support. Every rank computes all of them."""
    d = scene.domain
    layers = int(math.ceil(d.support / d.dx))
    if scene.initial.drop_radius > 0:
        rings = []
        for k in range(layers):
            r = scene.initial.drop_radius + (k + 0.5) * d.dx
            n = max(int(round(2.0 * math.pi * r / d.dx)), 3)
            theta = (np.arange(n) + 0.5 * (k % 2)) * 2.0 * math.pi / n
            rings.append(np.asarray(d.center) + r * np.stack([np.cos(theta), np.sin(theta)], axis=1))
        return np.concatenate(rings)
    if scene.free_surface_axis() is None:
        return np.zeros((0, d.dimension))
    from psph.boundaries import in_fluid_region as fills

    lo = np.asarray(scene.initial.fill_lower or d.lower, dtype=float)
    hi = np.asarray(scene.initial.fill_upper or d.upper, dtype=float)
    lattice = _lattice_within(scene, lo - d.support, hi + d.support)
    unbounded = replace(scene, initial=replace(scene.initial, fill_lower=(), fill_upper=()))
    candidates = lattice[fills(unbounded, lattice) & ~fills(scene, lattice)]
    beyond = np.maximum(np.maximum(lo - candidates, candidates - hi), 0.0)
    return candidates[np.sqrt((beyond * beyond).sum(axis=1)) <= d.support]


def _fitted_box(scene):
    """The scene's first unrotated box container, whose walls stand on rows fitted between its sides
    (psph.boundaries.solid_arrays), or None."""
    return next((b for b in scene.bodies if b.container and b.shape == "box" and b.angle == 0.0), None)


def fluid_volume(scene):
    """V_tot of seed 002's V0 = V_tot / N (text after eq. 2.17): the drop's area pi R^2, or in an unrotated
    box container the volume of the fill region that the fluid fills, over the cells of the walls' lattice
    (_lattice_within) inside the box and outside the bodies, each cell cut by the fill region, or None: the
    fluid's own lattice, N dx^d (another container's is a staircase of the fluid's points). A tank 1.95 wide
    at dx = 0.05 holds 1.95 of water in 39 fitted columns but 38 of the fluid's (dx^d each gave N V0 = 1.90,
    and a packed Gamma of 1.01: a packing audit); the dam-break column, B = 2 wide in a tank 5.367 wide,
    took the fitted cells whose centres it held, whole, which are not its own: V_tot off by -0.61% / +0.32%
    / -0.15% at dx = 0.1 / 0.05 / 0.025, and the flow's mass with it (a second packing audit)."""
    from psph.boundaries import in_fluid_region as fills
    from psph.boundaries import lattice_rows

    if scene.initial.drop_radius > 0:
        return math.pi * scene.initial.drop_radius ** 2
    box = _fitted_box(scene)
    if box is None:  # the fluid's own lattice: N dx^d
        return None
    rows, widths = lattice_rows(scene, *bounds(box))
    points = np.stack(np.meshgrid(*rows, indexing="ij"), axis=-1).reshape(-1, len(rows))
    cells = np.stack(np.meshgrid(*widths, indexing="ij"), axis=-1).reshape(-1, len(rows))
    ini = scene.initial
    unbounded = replace(scene, initial=replace(ini, fill_lower=(), fill_upper=()))
    lo = np.asarray(ini.fill_lower or [-np.inf] * len(rows), dtype=float)
    hi = np.asarray(ini.fill_upper or [np.inf] * len(rows), dtype=float)
    cut = np.clip(np.minimum(points + cells / 2.0, hi) - np.maximum(points - cells / 2.0, lo), 0.0, None)
    return float(np.prod(cut, axis=1)[fills(unbounded, points)].sum())


def _lattice_within(scene, lower, upper) -> np.ndarray:
    """The frame's lattice points inside the box [lower, upper]: an unrotated box container's rows, fitted
    between its sides where they are off the domain's lattice (psph.boundaries.extended_lattice), so that
    the frame meets the walls' first solid rows without a gap (from the domain's lattice, a tank 1.95 wide
    at dx = 0.05 left one of 1.5 dx beside each wall, and the packing drove fluid particles up it, above
    the free surface: a packing audit); across a side of the fill region inside the box, the fluid's own
    rows continued dx apart (the fitted ones stood 0.88-1.13 dx from the dam-break column's side, the whole
    of its start's largest grad Gamma: a second packing audit), while along it the frame keeps the fitted
    rows, which drift from the fluid's where the box is off the lattice (README, "Particle packing"); else
    the domain's cell-centred lattice (psph.initial.lattice_block)."""
    from psph.boundaries import lattice_rows

    d = scene.domain
    own = [d.lower[a] + (np.arange(d.lattice_shape()[a]) + 0.5) * d.dx for a in range(d.dimension)]
    box = _fitted_box(scene)
    if box is not None:
        rows = lattice_rows(scene, *bounds(box))[0]
        inner_lo, inner_hi = bounds(box)
        fill_lo = scene.initial.fill_lower or d.lower
        fill_hi = scene.initial.fill_upper or d.upper
        layers = np.arange(1, int(math.ceil(d.support / d.dx)) + 1) * d.dx
        tol = 1e-9 * d.dx
        for a in range(d.dimension):
            # across a fill side, the fitted rows up to the one nearest the fluid's last (first) row, then the
            # fluid's rows continued dx apart: the junction stands 0.5-1.5 dx wide (cut at the fluid's row, it
            # was 1-2 dx, and 1.87 dx at the dam-break column's top corner at dx = 0.05 let the packing blow
            # the column apart, T/beta 8.6, with exit 0: a review)
            if fill_hi[a] < inner_hi[a] - tol:
                last = own[a][own[a] <= fill_hi[a] + tol].max()
                cut = rows[a][np.argmin(np.abs(rows[a] - last))]
                rows[a] = np.concatenate([rows[a][rows[a] <= cut + tol], last + layers])
            if fill_lo[a] > inner_lo[a] + tol:
                first = own[a][own[a] >= fill_lo[a] - tol].min()
                cut = rows[a][np.argmin(np.abs(rows[a] - first))]
                rows[a] = np.concatenate([first - layers[::-1], rows[a][rows[a] >= cut - tol]])
    else:
        rows = own
    axes = [x[(x >= lower[a]) & (x <= upper[a])] for a, x in enumerate(rows)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d.dimension)


def _add_frame(scene, system, volume) -> int:
    """Append this rank's share of the frame particles (kind FRAME, volume V0 as the fluid's: seed 002
    eq. 2.14, 2.18) and rebuild. Returns the global count. Collective."""
    p, comm = system.particles, system.comm
    frame = frame_positions(scene)
    start, stop = len(frame) * comm.rank // comm.size, len(frame) * (comm.rank + 1) // comm.size
    first_gid = int(allreduce_max(comm, int(p.owned("gid").max()) if p.n_owned else -1)) + 1
    p.append_owned({"gid": first_gid + np.arange(start, stop, dtype=np.int64), "position": frame[start:stop],
                    "kind": np.full(stop - start, Kind.FRAME), "volume": np.full(stop - start, volume)},
                   fill={"body": -1})
    system.rebuild(rebalance=True)
    return len(frame)


def _remove_frame(system) -> None:
    """Drop the frame particles and the packing velocity, and rebuild. Collective."""
    p = system.particles
    keep = p.owned("kind") != Kind.FRAME
    p.remove_field(VELOCITY.name)
    p.set_owned({name: values[keep] for name, values in p.owned_arrays().items()})
    system.rebuild(rebalance=True)


def set_packed_volume(scene, system) -> float:
    """Give the owned fluid particles seed 002's V0 = V_tot / N (fluid_volume; N dx^d where it is None) and
    return it. Collective."""
    d = scene.domain
    n_fluid = int(allreduce_sum(system.comm, int(np.count_nonzero(fluid_mask(system)))))
    total = fluid_volume(scene)
    v0 = d.dx ** d.dimension if total is None else total / n_fluid
    system.particles.owned("volume")[fluid_mask(system)] = v0
    return v0


def start_from_snapshot(scene, system, path) -> dict:
    """Move the owned fluid particles to their positions (by gid) in the psph snapshot `path`
    (packing.start), give them V0 (set_packed_volume) and rebuild: a packing done once serves later runs
    of the scene. The file must hold this scene's fluid, gid for gid, and its other particles where the
    scene has them (the same walls and bodies): anything else is a SceneError naming packing.start and
    what differs. Returns {start, start_time, start_step}. Collective (rank 0 reads the file for all)."""
    from psph.errors import SceneError
    from psph.io.snapshots import h5py
    from psph.parallel.comm import on_root

    comm, p, d = system.comm, system.particles, scene.domain
    key, dim = "packing.start", d.dimension

    def read():
        if not Path(path).is_file():
            raise SceneError(key, f"no file {path}")
        try:
            with h5py.File(path, "r") as f:
                group = f["particles"]
                arrays = tuple(np.asarray(group[name][()]) for name in ("gid", "kind", "position"))
                return arrays, {name: f.attrs[name].item() for name in ("time", "step")}
        except KeyError as err:
            raise SceneError(key, f"{path} is not a psph snapshot ({err})") from None
        except OSError as err:
            raise SceneError(key, f"cannot read {path}: {' '.join(str(err).split())}") from None

    (gid, kind, pos), attrs = on_root(comm, read)  # (a style audit: a file one rank could not read stopped it alone)
    if pos.ndim != 2 or pos.shape[1] != dim or len(gid) != len(pos) or len(kind) != len(pos):
        raise SceneError(key, f"{path} holds positions of shape {pos.shape}, not n x {dim} beside its gids")
    fluid = fluid_mask(system)
    n_scene = int(allreduce_sum(comm, int(np.count_nonzero(fluid))))
    n_file = int(np.count_nonzero(kind == Kind.FLUID))
    if n_file != n_scene:
        raise SceneError(key, f"{path} holds {n_file} fluid particles, this scene {n_scene} (another dx, fill "
                         "or geometry?)")
    order = np.argsort(gid)
    gid, kind, pos = gid[order], kind[order], pos[order]
    own_gid, own_kind = p.owned("gid"), p.owned("kind")
    at = np.minimum(np.searchsorted(gid, own_gid), max(len(gid) - 1, 0))
    found = (gid[at] == own_gid) & (kind[at] == own_kind) if len(gid) else np.zeros(len(own_gid), dtype=bool)
    here = p.owned("position").copy()
    system.domain.wrap(here)
    moved = np.abs(pos[at] - here).max(axis=1) > 1e-6 * d.dx if len(gid) else found
    error = None
    bad = np.flatnonzero(~found | (~fluid & moved))
    if bad.size:
        k = int(bad[0])
        what = f"{'fluid' if fluid[k] else Kind(int(own_kind[k])).name.lower()} particle gid {int(own_gid[k])}"
        where = np.array2string(here[k], precision=6)
        error = SceneError(key, f"{path} puts this scene's {what} at {np.array2string(pos[at][k], precision=6)}, "
                           f"not {where} (another geometry?)" if found[k] else
                           f"{path} does not hold this scene's {what} (at {where}; another geometry, or a "
                           "snapshot after particles left or entered?)")
    else:
        start = pos[at][fluid]
        bad = np.flatnonzero(~np.isfinite(start).all(axis=1) | system.domain.outside(start) | ~_near_fill(scene, start))
        if bad.size:
            k = int(bad[0])
            error = SceneError(key, f"{path} puts fluid gid {int(own_gid[fluid][k])} at "
                               f"{np.array2string(start[k], precision=6)}, more than dx/2 outside this scene's fluid "
                               "region (the fill region or drop): a later state of a flow?")
    raise_if_any(comm, error)
    p.owned("position")[fluid] = pos[at][fluid]
    system.rebuild(rebalance=True)
    set_packed_volume(scene, system)
    return {"start": str(path), "start_time": float(attrs["time"]), "start_step": int(attrs["step"])}


def _near_fill(scene, points) -> np.ndarray:
    """Which points lie within dx/2 (along an axis) of the scene's fluid region (psph.boundaries.in_fluid_region:
    the fill region or drop, outside the bodies): where a packing keeps its particles (the drop's frame
    starts dx/2 outside its rim; a packing audit's t = 0.1 snapshot of the stretched drop, started from
    and packed, put particles into the frame and diverged, blaming packing.cfl)."""
    from psph.boundaries import in_fluid_region as fills

    d = scene.domain
    near = fills(scene, points)
    for offset in np.concatenate([np.eye(d.dimension), -np.eye(d.dimension)]) * 0.5 * d.dx:
        near |= fills(scene, points + offset)
    return near


def pack(scene, system, rows=None) -> dict:
    """Pack the fluid particles of `system` (seed 002 eq. 2.16; module docstring) and set their volumes to
    V0. Returns a report: iterations, whether T fell below the tolerance, T / beta, Linf(grad Gamma) h over
    the fluid (frame included) before and after, V0, the frame's size, the wall time and the history rows
    (iteration, T / beta, Linf(grad Gamma) h), appended as they come to `rows` if given (a failure leaves
    them there). A non-finite state stops every rank with a NumericalError naming the iteration and a
    particle. Collective."""
    spec, d = scene.packing, scene.domain
    comm, p, h = system.comm, system.particles, system.kernel.h
    start = time.perf_counter()
    v0 = set_packed_volume(scene, system)
    n_frame = _add_frame(scene, system, v0)
    p.add_field(VELOCITY)
    spacing = v0 ** (1.0 / d.dimension)
    dt = spec.cfl * min(spacing, 0.5 * h)
    damping = 1.0 + spec.alpha / spacing * dt  # 1 + zeta dt
    grad = grad_c(system)
    _, linf_start = norms(comm, grad, fluid_mask(system), h)
    rows = [] if rows is None else rows
    rows.append((0, 0.0, linf_start))
    kinetic, linf, iteration, done = 0.0, linf_start, 0, False
    while iteration < spec.iterations:
        iteration += 1
        fluid = fluid_mask(system)
        u = p.owned(VELOCITY.name)
        u[fluid] = (u[fluid] - dt * grad[fluid]) / damping
        p.owned("position")[fluid] += dt * u[fluid]
        _check_finite(system, iteration)
        try:
            system.update()
        except NumericalError as err:  # raised on every rank: an escaped particle
            # the message names the particle already (the ranks that did not hold it rebuilt the error from it)
            failure = NumericalError(f"particle packing diverged at iteration {iteration}: {err}; lower packing.cfl")
            failure.collective = True
            raise failure from None
        grad = grad_c(system)
        u, fluid = p.owned(VELOCITY.name), fluid_mask(system)
        kinetic, terminal = allreduce_sum(comm, np.array([0.5 * float((u[fluid] ** 2).sum()),
                                                          0.5 * float((grad[fluid] ** 2).sum())]))
        kinetic = float(kinetic)
        # at rest only once the forces have had a damping time 1 / zeta to set the particles moving, or where
        # they would not (T at the terminal speeds |grad Gamma| / zeta below the tolerance too): the start is
        # at rest, and its first T, (dt |grad Gamma|)^2 / 2, fell below the tolerance with a small packing.cfl
        # (1e-4: "converged" after one iteration, the drop still its raw lattice; a second packing audit)
        settled = iteration * (damping - 1.0) >= 1.0 or terminal / (damping - 1.0) ** 2 * dt * dt < spec.tolerance
        done = bool(kinetic < spec.tolerance and settled)
        if iteration % RECORD_EVERY == 0 or done or iteration == spec.iterations:
            _, linf = norms(comm, grad, fluid, h)
            rows.append((iteration, kinetic, linf))
        if done:
            break
    converged = done
    _check_no_pairs(scene, system, spacing, iteration, converged)
    _check_held(scene, system, iteration, kinetic)
    _remove_frame(system)
    return {"iterations": iteration, "converged": converged, "kinetic_energy": kinetic,
            "Linf_grad_gamma_start": linf_start, "Linf_grad_gamma": linf, "volume": v0, "frame_particles": n_frame,
            "time_s": time.perf_counter() - start, "rows": rows}


PAIRED = 0.5  # a packed fluid particle closer than this many V0^(1/d) to another particle is paired


def _check_held(scene, system, iteration, kinetic) -> None:
    """Stop every rank if the packing carried a fluid particle more than dx/2 outside the fluid region
    (_near_fill): the walls and the frame did not hold the fluid (a review: a gap in the dam-break column's
    frame at dx = 0.05 let the packing blow the column over the tank, T/beta 4.2 after 1000 iterations, and
    the flow started from there with exit 0). Collective."""
    p = system.particles
    fluid = fluid_mask(system)
    out = np.flatnonzero(~_near_fill(scene, p.owned("position")[fluid]))
    error = None
    if out.size:
        k = int(np.flatnonzero(fluid)[out[0]])
        error = NumericalError(f"particle packing carried the fluid out of its region by iteration {iteration} "
                               f"(T/beta = {kinetic:.3g}): the walls and the frame did not hold it",
                               gid=int(p.owned("gid")[k]), position=p.owned("position")[k])
    raise_if_any(system.comm, error)


def _check_no_pairs(scene, system, spacing, iteration, converged) -> None:
    """Stop every rank if the packing ended with a fluid particle closer than PAIRED spacings to another
    (fluid, wall or frame): a kernel whose pairing instability the fictitious dynamics found (a packing
    audit: the cubic spline at h/dx = 2 stacked 176 of a drop's 316 particles within 0.01 dx of another,
    with grad Gamma small, and the run went on), or a packing stopped by packing.iterations while its
    particles still moved (the message says which: a fuzzing audit found the second blamed on the kernel).
    Collective."""
    p = system.particles
    r, k = closest_pair(p["position"], p["kind"] == Kind.FLUID, system.nbr_ptr, system.nbr_idx)
    nearest = global_first(system.comm, (-float(r), int(p["gid"][k]), p["position"][k].copy()) if k >= 0 else None)
    close, gid_min, where = (np.inf, 0, None) if nearest is None else (-nearest[0], nearest[1], nearest[2])
    if close < PAIRED * spacing:
        why = ("the packing had not converged (its kinetic energy above packing.tolerance): raise "
               "packing.iterations" if not converged else
               f"the kernel's pairing instability; domain.kernel = {scene.domain.kernel!r} at h/dx = "
               f"{scene.domain.h_over_dx:g}" + (": use a Wendland kernel" if "wendland" not in scene.domain.kernel
                                                else ""))
        error = NumericalError(f"particle packing paired particles at iteration {iteration}: two lie "
                               f"{close / spacing:.2g} V0^(1/d) apart ({why})", gid=gid_min, position=where)
        error.collective = True
        raise error


def _check_finite(system, iteration) -> None:
    """Stop every rank if a packed position or velocity is not finite. Collective."""
    p = system.particles
    bad = ~(np.isfinite(p.owned("position")).all(axis=1) & np.isfinite(p.owned(VELOCITY.name)).all(axis=1))
    error = None
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        error = NumericalError(f"particle packing diverged at iteration {iteration} (non-finite position or "
                               "velocity; lower packing.cfl)", gid=int(p.owned("gid")[k]),
                               position=p.owned("position")[k])
    raise_if_any(system.comm, error)
