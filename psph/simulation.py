"""Assembling a simulation from a scene: domain, kernel, distributed particles, output writers."""

import json
import time
import uuid
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

from psph import __version__, stop
from psph.compute.smoothing import make_kernel
from psph.compute.warmup import warm_up
from psph.domain import Domain
from psph.initial import create_particles
from psph.io.history import History, write_summary
from psph.io.snapshots import SnapshotWriter
from psph.parallel.comm import allreduce_max, allreduce_sum, on_root
from psph.profiling import memory
from psph.scene.validate import to_table
from psph.system import BASE_HALO_FIELDS, ParticleSystem


def make_domain(scene) -> Domain:
    d = scene.domain
    margin = 2.0 * (d.support + d.dx) if scene.bodies else 0.0  # the walls' solid layers lie outside
    return Domain(lower=tuple(d.lower), upper=tuple(d.upper), periodic=tuple(d.periodic), margin=margin,
                  outflow=d.outflow_faces())


def build_system(scene, comm, specs=(), halo_fields=BASE_HALO_FIELDS, particles=None,
                 decomposition=None) -> ParticleSystem:
    """The particles of `scene` (initial ones unless `particles`, e.g. from a checkpoint, are given),
    decomposed over `comm` (from `decomposition` if given), with halo and neighbour lists. Collective."""
    d = scene.domain
    kernel = make_kernel(d.kernel, d.dimension, d.h)
    if particles is None:
        particles = create_particles(scene, comm, specs)
    return ParticleSystem(comm, make_domain(scene), kernel, particles, skin=scene.neighbours.skin,
                          rebalance_threshold=scene.neighbours.rebalance_threshold, halo_fields=halo_fields,
                          decomposition=decomposition)


def unperturbed(scene):
    """The same scene on the unperturbed lattice (the Cartesian reference of the thesis' figures)."""
    return replace(scene, initial=replace(scene.initial, sigma_over_dx=0.0))


class Simulation:
    """A scene set up on a communicator with its output directory. Drivers advance it.

    restart: (state, particles, decomposition) from io.checkpoint.read_checkpoint: the particles, the
    history rows and the snapshot index continue from the checkpoint; history.csv and psph.xdmf are
    rewritten from them at once (an earlier run's later rows and snapshots never sit beside the
    continuation's), and the continued run's checkpoints in `out_dir` up to it are replaced by the first
    checkpoint written (no other file is removed)."""

    def __init__(self, scene, comm, out_dir, *, specs=(), halo_fields=BASE_HALO_FIELDS, log=None, restart=None,
                 progress=False):
        """Set up the run's output directory, kernels and particles. Collective."""
        self.started = time.perf_counter()
        self.scene = scene
        self.summary_extra = {}  # what the caller adds to summary.json (the command line: the IIPS solver)
        self.on_settled = None  # what the caller does once the run has set up (settle)
        self.comm = comm.Dup()
        self.out_dir = Path(out_dir)
        on_root(self.comm, lambda: self.out_dir.mkdir(parents=True, exist_ok=True))  # (every rank's failure)
        self.log = log or (lambda msg: None)
        self.show_progress = progress
        _warm_up(self.comm, scene)
        state, particles, decomposition = restart or (None, None, None)
        # the wall time of the segments before this one (a checkpoint of an older psph carries none: 0)
        self.earlier_wall_time = float((state or {}).get("wall_time_s", 0.0))
        # the run's id, on its snapshots, checkpoints and summary; a continuation keeps it (a checkpoint of an
        # older psph carries none: the continuation's files get a new one)
        self.run = (state or {}).get("run") or self.comm.bcast(uuid.uuid4().hex if self.comm.rank == 0 else None)
        self.system = build_system(scene, self.comm, specs, halo_fields, particles, decomposition)
        self.snapshots = SnapshotWriter(self.comm, self.out_dir, self.system.domain, run=self.run,
                                        scene=json.dumps(to_table(scene)))
        self.history = History(self.comm, self.out_dir)
        # the run's particle count at its start: a continuation's is the checkpoint's record, not the count it
        # holds (open boundaries emit and remove particles: a continued jet's summary said 2016 against 1936,
        # a restarts audit; a checkpoint of an older psph carries none)
        self.n_particles = int((state or {}).get("n_particles", self.system.n_global))
        self.replaced_checkpoints = []  # rank 0: what the next checkpoint replaces (this run's own)
        if state is not None:
            from psph.io.checkpoint import checkpoints_up_to

            self.system.rebuilds = state["rebuilds"]
            self.history.restore(state["history"])
            self.history.flush()
            self.snapshots.restore(state["snapshots"])
            if self.comm.rank == 0:
                self.replaced_checkpoints = checkpoints_up_to(self.out_dir, state["step"])

    def close(self) -> None:
        """Free the communicators of the simulation and its system (its output stays). Collective; the PETSc
        objects made on them must have been destroyed first (the drivers' close)."""
        from psph.solvers.petsc import release_comm

        self.system.close()
        release_comm(self.comm)

    # ------------------------------------------------------------ checkpoints
    def checkpoint_due(self, step, last_wall) -> bool:
        """Every output.checkpoint_every steps, or output.checkpoint_minutes of wall time (rank 0's clock
        decides, so all ranks agree). Collective."""
        out = self.scene.output
        if out.checkpoint_every and step % out.checkpoint_every == 0:
            return True
        if out.checkpoint_minutes:
            return bool(self.comm.bcast(time.monotonic() - last_wall >= 60.0 * out.checkpoint_minutes, root=0))
        return False

    def wall_time(self) -> float:
        """The run's wall time so far, the segments before its restarts included (rank 0's clock). Collective."""
        return self.comm.bcast(time.perf_counter() - self.started + self.earlier_wall_time, root=0)

    def checkpoint(self, step, t, driver: dict) -> Path:
        """Rebuild the lists (a restart must rebuild them, so the continued run stays bit for bit) and write
        OUT/checkpoint_NNNNNN.h5 with the particles, history, snapshot index, scene and the driver's
        state `driver` (JSON-able); returns its path. Collective."""
        from psph.io.checkpoint import write_checkpoint

        self.system.rebuild(rebalance=False)
        path = write_checkpoint(self.comm, self.out_dir, self.system, step, t, {
            "scene": to_table(self.scene), "driver": driver, "history": self.history.rows,
            "snapshots": self.snapshots.checkpoint_state(), "wall_time_s": self.wall_time(), "run": self.run,
            "n_particles": self.n_particles},
            replaces=self.replaced_checkpoints)
        self.replaced_checkpoints = [path]
        self.log(f"step {step}, t = {t:.4g}: checkpoint {path.name}")
        return path

    def snapshot_once(self, step: int, t: float, extra=None):
        """Write a snapshot of the state at `step` unless the last one written is of it; its path either way.
        `extra`: a callable returning the extra owned arrays (called only to write). Collective."""
        entries = self.snapshots.entries
        if entries and entries[-1][2] == step:
            return self.out_dir / entries[-1][0]
        return self.snapshots.write(self.system.particles, step=step, time=t, extra=extra() if extra else None)

    def stop_requested(self) -> bool:
        """Whether a signal asked the run to stop (psph.stop). Collective."""
        return bool(stop.requested(self.comm))

    def stop(self, message: str) -> None:
        """End a run asked to stop: flush the history and raise psph.stop.Stopped with `message` (what was
        saved where). Collective."""
        self.history.flush()
        raise stop.Stopped(stop.requested(self.comm), message)

    def settle(self) -> None:
        """The run has set up (its start built and checked, its pre-procedure done) and its loop begins: call
        on_settled, once (the command line then lets go of the results --overwrite replaces)."""
        if self.on_settled is not None:
            settled, self.on_settled = self.on_settled, None
            settled()

    def progress(self, t_start, t_end):
        """A Progress display for a time loop (rank 0, if the run shows progress)."""
        from psph.progress import Progress

        return Progress(self.comm, t_start, t_end, enabled=self.show_progress)

    @contextmanager
    def diagnose_failures(self, where):
        """On a NumericalError inside the block, write a diagnostic snapshot (the state at failure, with
        grad C) before letting the error end the run. It is labelled with the error's step and time (a
        failure inside the integration: that step and the time it started from; one the checks after the
        step find, an IIPS call's among them: that step and the time it ended at, the state's), else with
        `where()`'s (step, time) (the last completed step). Collective: the error is every rank's
        (raise_if_any), with its WHERE; one rank's NumericalError, like any other error (a full disk, a bug,
        a forced stop), leaves the history's rows so far written (rank 0, no collective), unless writing them
        fails too."""
        from psph.diagnostics import grad_c
        from psph.errors import NumericalError, is_collective

        try:
            yield
        except NumericalError as err:
            if self.comm.size > 1 and not is_collective(err):
                # one rank's error: the snapshot is collective and the other ranks are elsewhere (a hang, once
                # the snapshot's first collective matched theirs); the CLI aborts them with this error
                self._flush_quietly()
                raise
            step, t = where()
            step = step if getattr(err, "step", None) is None else err.step
            t = t if getattr(err, "time", None) is None else err.time
            self.history.flush()
            path = self.snapshots.write(self.system.particles, step=step, time=t,
                                        extra={"grad_c": grad_c(self.system)})
            self.log(f"psph: state at the failure written to {path}")
            raise
        except BaseException:  # a bug, a full disk, a forced stop (KeyboardInterrupt): rank 0 only, no collective
            self._flush_quietly()
            raise

    def _flush_quietly(self) -> None:
        """Write the history's rows so far (rank 0, no collective), unless that fails too: the error being
        raised says more."""
        try:
            self.history.flush()
        except Exception:
            pass

    def summary(self, steps: int, final: dict, **extra) -> dict:
        """Flush the history, write summary.json (collective call; rank 0 writes) and return it."""
        self.history.flush()
        peak = memory()[1]
        data = {
            "psph_version": __version__,
            "run": self.run,
            "scene": to_table(self.scene),
            "ranks": self.comm.size,
            "n_particles": self.n_particles,
            "steps": steps,
            "wall_time_s": self.wall_time(),
            "neighbour_rebuilds": self.system.rebuilds,
            # resident memory at its peak (profiling.memory): the largest rank's, and all ranks' summed (an
            # upper bound: shared pages count on every rank, and the ranks peak at different moments)
            "peak_memory_mib": allreduce_max(self.comm, peak) / 2**20,
            "peak_memory_mib_total": allreduce_sum(self.comm, peak) / 2**20,
            "final": final,
        }
        data.update(extra)
        data.update(self.summary_extra)
        write_summary(self.comm, self.out_dir, data)
        return data


# Memory model of estimate_resources, its constants from the peaks runs reach (summary.json's peak_memory_mib;
# run_scripts/bench_memory.py prints the model against them)
BASE_BYTES = 256 * 2**20  # per rank before any particle: Python, numpy, numba's kernels, PETSc, MPI, h5py
LIST_ENTRY_BYTES = 20  # per neighbour-list entry: its index (4), the search's work copies, pair caches
AIJ_ENTRY_BYTES = 18  # per assembled-matrix nonzero: value and column (12), its slot (4), the build's copies
AIJ_SPLIT_ENTRY_BYTES = 30  # the same on several ranks, whose build also splits the pattern into two blocks
FIELD_DOUBLES = {True: 64, False: 16}  # per local particle, fluid runs (fields, Runge-Kutta stages) or not
WALLS_FACTOR = 1.5  # per lattice point with bodies: their solid particles, solid fields and clone terms


def warm_up_parts(scene) -> frozenset:
    """The parts (compute.warmup.PARTS) of the kernels a run of `scene` calls."""
    from psph.scene.schema import FLUID_SCHEMES

    parts = set()
    if scene.physics.scheme in FLUID_SCHEMES:
        parts.add("fluid")
        models = {b.model for b in scene.bodies}
        parts.update(name for name, present in (
            ("riemann", scene.physics.scheme == "riemann_ale"), ("delta_ale", scene.physics.scheme != "riemann_ale"),
            ("walls", "clone" in models), ("ghost_walls", "ghost" in models),
            ("open", scene.domain.outflow_buffer or any(f.density == "extrapolated" for f in scene.inflow)),
            ("free_surface", bool(scene.describe_free_surface())),
            ("shifting", scene.shifting.method not in ("none", "iips")),
            ("field_update", iips_runs(scene) and scene.iips.update != "none")) if present)
    if iips_runs(scene):
        parts.add("assembled" if iips_assembled(scene) else "iips")
    return frozenset(parts)


def _warm_up(comm, scene) -> None:
    """Compile (or load) the kernels a run of `scene` calls (compute.warmup, warm_up_parts) on one rank of
    each machine, then load them from numba's cache on the others: ranks compiling at once each compiled
    everything, wrote the cache's index at once and, more ranks than cores, shared the cores while doing so
    (Taylor-Green on a cold cache: 39 s of wall time on one rank, 40 s on two, which spent 76 s of CPU,
    either way: the waiting rank polls). Collective."""
    from mpi4py import MPI

    args = (scene.domain.dimension, scene.domain.kernel, warm_up_parts(scene))
    node = comm.Split_type(MPI.COMM_TYPE_SHARED)
    try:
        error = None
        if node.rank == 0:
            try:
                warm_up(*args)
            except Exception as failure:  # the machine's other ranks must not wait for it
                error = failure
        if node.bcast(error is not None, root=0):
            raise error or RuntimeError("compiling psph's kernels failed on another rank of this machine")
        if node.rank > 0:
            warm_up(*args)
    finally:
        node.Free()


def iips_runs(scene) -> bool:
    """Whether a run of `scene` builds an IIPS operator: IIPS shifting, or the static pre-procedure."""
    return scene.shifting.method == "iips" or scene.iips.pre_newton > 0


def iips_assembled(scene) -> bool:
    """Whether a run of `scene` builds the assembled IIPS matrix, under PETSc's options as they stand (the
    command line, PETSC_OPTIONS, options files: initialise PETSc with the run's options first), as the run
    itself decides (psph.shifting.iips_operator.assembles)."""
    from psph.shifting.iips import PREFIX
    from psph.shifting.iips_operator import assembles

    return iips_runs(scene) and assembles(scene.iips.operator, PREFIX)


def initial_particles_bound(scene) -> int:
    """An upper bound on a scene's particles at the start, without building them (a new user's audit: a 3-D
    column filling an eighth of its box was counted as the whole box, 6400 for 800): the lattice nodes, both
    faces of a box counted, of the fill box within the domain; of an outflow buffer across it, a support and
    a node deep, at each buffered outflow face; of each immersed body's box within the domain widened by a
    support and a node (solid particles lie past the domain's faces: a plate going on past an outflow face);
    and of the box around the strip that wide on the solid side of each side of a container, from a support
    and a node before its start to as far past its end (a review: a band along the domain's faces missed the
    walls of a tank's baffles inside it, 6326 for 9836). Not the inflow buffers' particles
    (estimate_resources counts the whole domain where there are any)."""
    import math

    import numpy as np

    from psph.boundaries.bodies import bounds, container_sides

    d = scene.domain
    band = d.support + d.dx
    lower, upper = np.asarray(d.lower, dtype=float), np.asarray(d.upper, dtype=float)

    def nodes(lo, hi, within=(lower, upper)):
        extent = np.minimum(hi, within[1]) - np.maximum(lo, within[0])
        return math.prod(math.floor(x / d.dx + 1e-9) + 1 if x >= 0.0 else 0 for x in extent)

    fill = (np.asarray(scene.initial.fill_lower or d.lower, dtype=float),
            np.asarray(scene.initial.fill_upper or d.upper, dtype=float))
    n = nodes(*fill)
    for a, _ in d.outflow_faces() if d.outflow_buffer else ():
        lo, hi = fill[0].copy(), fill[1].copy()
        lo[a], hi[a] = lower[a], lower[a] + band  # the buffer's layers, across the fill's cross-section
        n += nodes(lo, hi)
    wide = (lower - band, upper + band)
    for b in scene.bodies:
        if not b.container:  # its solid particles are inside it
            n += nodes(*bounds(b), within=wide)
            continue
        for a, e in container_sides(b):  # the strip on the solid side, past both ends (the corners)
            along = (e - a) / np.linalg.norm(e - a)
            out = np.array([along[1], -along[0]])
            corners = np.array([a - band * along, e + band * along])
            corners = np.concatenate([corners - d.dx * out, corners + band * out])
            n += nodes(corners.min(axis=0), corners.max(axis=0), within=wide)
    return n


def estimate_resources(scene, ranks=1, assembled=False) -> tuple:
    """(particles, bytes, bytes per particle) a run of `scene` on `ranks` ranks needs, before allocating
    anything; `assembled`: with the assembled IIPS matrix (iips_assembled).

    BASE_BYTES per rank, and per particle: its fields, for the particle and for its copies in other
    ranks' halos (a rank's share taken as a cube of particles, its halo the list radius around it); its
    neighbour list (LIST_ENTRY_BYTES per entry, the neighbours within the support and the skin); with
    IIPS the matrix-free operator's pairs (half the support's neighbours, d (d + 1) / 2 doubles and a
    4-byte column each) and vectors, or the assembled matrix's d^2 entries per list entry and its own
    d^2 (AIJ_ENTRY_BYTES each, AIJ_SPLIT_ENTRY_BYTES on several ranks); with bodies the particle's part
    times WALLS_FACTOR. The particles are the domain's lattice points, or, with no inflow (particles can
    only leave), initial_particles_bound's if fewer. The constants make it an upper estimate, 1.06-1.45 times the peaks
    run_scripts/bench_memory.py measures (48 runs: 12 cases, 2-D and 3-D, 1 and 2 ranks).
    """
    import math

    d = scene.domain
    dim = d.dimension

    def ball(r):
        return {1: 2.0 * r, 2: math.pi * r**2, 3: 4.0 / 3.0 * math.pi * r**3}[dim]

    support = d.support / d.dx
    radius = (1.0 + scene.neighbours.skin) * support
    n = d.estimated_particles()
    if scene.initial.drop_radius > 0:  # the disc's lattice points, and the packing's frame around it
        n = math.ceil(math.pi * (scene.initial.drop_radius + d.support) ** 2 / d.dx**2)
    elif not scene.inflow:  # the particles can only leave: the fill's and the solids' at the start
        n = min(n, initial_particles_bound(scene))
    side = max(n / max(ranks, 1), 1.0) ** (1.0 / dim)
    halo = ((side + 2.0 * radius) / side) ** dim - 1.0
    fluid = scene.physics.scheme not in ("none", "kinematic")
    per_particle = 8 * FIELD_DOUBLES[fluid] * (1.0 + halo) + LIST_ENTRY_BYTES * ball(radius)
    if scene.bodies:
        per_particle *= WALLS_FACTOR
    if iips_runs(scene):
        if assembled:
            entry = AIJ_ENTRY_BYTES if ranks == 1 else AIJ_SPLIT_ENTRY_BYTES
            per_particle += entry * dim**2 * (ball(radius) + 1.0)
        else:
            per_particle += ball(support) / 2.0 * (4 + 4 * dim * (dim + 1)) + 8 * 6 * dim
    return n, n * per_particle + ranks * BASE_BYTES, per_particle


def estimate_time_step(scene) -> str:
    """The time step a run of `scene` starts with and its number of steps, as a line (empty for static runs):
    time_step_estimate's."""
    dt, how, steps = time_step_estimate(scene)
    if dt is None:
        return ""
    count = f"{steps}" if steps < 1e9 else f"{steps:.3g}"  # (a failure audit: nu = 1e304 printed 304 digits)
    return f"estimated time step: {dt:.4g} ({how}), about {count} steps to t_end = {scene.time.t_end:g}"


# the largest diagonal weight of a fluid row beside a flat no-slip clone wall over the lattice's (the row at dx/2
# from it, Wendland C6 at h = 2 dx: compute.walls.clone_viscous_weight), by viscous operator (a review)
NO_SLIP_WALL_WEIGHT = {"morris": 1.42, "pi_ij": 1.20}


def time_step_estimate(scene) -> tuple:
    """(dt, how it was found, steps to t_end) a run of `scene` starts with, or (None, "", 0) for a static run.

    Fluid: cfl h / (c0 + U) (thesis eq. 5.52, U the reference velocity; the run adapts it to the actual
    speed) and at most the viscous operator's limit on the lattice (psph.schemes.viscous_limit; disorder
    lowers it in the run); kinematic: cfl dx / c0."""
    import math

    d, ph, t = scene.domain, scene.physics, scene.time
    if ph.scheme == "none":
        return None, "", 0
    if ph.scheme == "kinematic":
        dt = t.cfl * d.dx / ph.sound_speed
        how = f"cfl dx / c0 = {t.cfl:g} x {d.dx:g} / {ph.sound_speed:g}"
    else:
        from psph.schemes import make_scheme

        scheme = make_scheme(scene)
        dt = t.cfl * d.h / (scheme.c0 + ph.reference_velocity)
        how = f"cfl h / (c0 + U) = {t.cfl:g} x {d.h:g} / ({scheme.c0:g} + {ph.reference_velocity:g})"
        if scheme.nu > 0:
            from psph.compute.smoothing import make_kernel
            from psph.schemes.viscous_limit import ViscousLimit

            limit = ViscousLimit.of_scene(scene, scheme, make_kernel(d.kernel, d.dimension, d.h))
            if limit.step < dt:
                dt = limit.step
                how = (f"viscous limit {limit.step * scheme.nu / d.h**2:.3g} h^2 / nu on the lattice, h = {d.h:g}, "
                       f"nu = {scheme.nu:g}")
            wall = NO_SLIP_WALL_WEIGHT["morris" if scheme.morris else "pi_ij"]
            if limit.step / wall < dt and any(b.wall == "no_slip" and b.model == "clone" for b in scene.bodies):
                dt = limit.step / wall  # (a review: 550 steps said, 779 run)
                how = (f"viscous limit {limit.step * scheme.nu / d.h**2:.3g} h^2 / nu on the lattice, / {wall:g} "
                       f"beside a flat no-slip wall (clone_viscous_weight), h = {d.h:g}, nu = {scheme.nu:g}")
    steps = t.t_end / dt if dt > 0.0 else math.inf  # (a fuzzing test: U = 2e305 made the viscous limit 0)
    return dt, how, math.ceil(steps) if steps < 1e15 else steps


def machine_memory() -> int:
    import os

    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


MAX_STEPS = 1e9  # more steps than a run takes in a year at 30 ms a step


def check_resources(scene, allow_large=False, ranks=1, node_ranks=None) -> None:
    """Refuse (SceneError on domain.dx) a scene whose estimated memory (estimate_resources, with the IIPS
    operator PETSc's options choose) exceeds 80% of this machine's: the share of `node_ranks` of the run's
    `ranks` ranks (all of them if None; on a cluster, the ranks on this node); and (on time.t_end) one that
    would take more than MAX_STEPS steps (time_step_estimate)."""
    from psph.errors import SceneError

    n, nbytes, _ = estimate_resources(scene, ranks, iips_assembled(scene))
    here = ranks if node_ranks is None else node_ranks
    need = (nbytes - ranks * BASE_BYTES) * here / ranks + here * BASE_BYTES
    on = "" if here == ranks else f" on this machine ({here} of the run's {ranks} ranks)"
    if need > 0.8 * machine_memory() and not allow_large:
        raise SceneError("domain.dx", f"{n} particles need about {need / 2**30:.3g} GiB{on}, more than 80% of "
                         f"this machine's {machine_memory() / 2**30:.3g} GiB (run with --allow-large to try anyway)")
    dt, how, steps = time_step_estimate(scene)
    if steps > MAX_STEPS and not allow_large:  # (a failure audit: Re = 1e-300 ran 77 440 steps to t = 5e-299)
        raise SceneError("time.t_end", f"{scene.time.t_end:g} takes about {steps:.3g} steps of {dt:.3g} ({how}), "
                         f"more than {MAX_STEPS:.0e} (run with --allow-large to try anyway)")
