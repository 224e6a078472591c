"""Open boundaries: inflow buffers and outflow faces (README, "Open boundaries").

An inflow buffer is a box of particles (Kind.INLET) on a lattice of spacing dx that move at the prescribed
velocity U along one axis, their density (with its pressure and mass) the Shepard average of the fluid's
beside them, set after every step (inflow.density = "extrapolated", the default) or rho0 and its pressure
("prescribed"); they take part in their fluid neighbours' sums as fluid particles do, but the scheme gives
them no rates and no shifting moves them (they are not IIPS unknowns: thesis 000 section 10.2.1). A buffer
at least one kernel support deep gives the fluid beside it a full support. With xi the distance downstream
of the buffer's upstream face and D its depth:

    rows at t = 0          xi_k = (k + 1/2) dx,  k = 0 .. D/dx - 1
    row m emitted          when |U| t >= m dx, at xi = (1/2 - m) dx + |U| t   (m = 1, 2, ...)
    a particle joins       the fluid (Kind.FLUID) once xi > D

so every row travels on the same lattice and the buffer lets |U| rho0 dx^(d-1) of mass in per unit area
and time, whatever the time step. With `profile = "parabolic"` each column of the buffer (a point of its
cross-section, transverse coordinates s_a scaled to 0..1 across the section) moves at its own speed
|U| prod_a 4 s_a (1 - s_a), Poiseuille's profile with U at the centre (its mean over a 2-D section 2/3 U;
over a 3-D one, the product of two parabolas, 4/9 U, which only approximates a square duct's), and emits its
own rows by the rule above at that speed. Which rows exist depends on t only: runs on any number of ranks
emit the same particles with the same gids. A non-reflecting buffer (`non_reflecting_time`) moves at U plus
an acoustic speed it takes from the fluid after every step (OpenBoundaries.follow_sound), and its rows
follow its travel, which depends on the fluid's means over all ranks too (the same to round-off).

At an outflow face (domain.outflow) fluid particles that crossed it
are removed; with `domain.outflow_buffer` they become buffer particles (Kind.OUTLET) instead, removed one
kernel support past the face (a run starts with the buffer full: fill_outflow_buffers), whose density,
pressure and velocity are set after every step to the Shepard average of their fluid neighbours (a zero-
gradient extrapolation, compute.sums.shepard_from_fluid). The fluid beside the face then has a full support
and sees there the state it would see inside: a sound wave passes out (2.4% reflected) instead of being
reflected as from a free surface (65%). Each change of the particle set is followed by a neighbour rebuild, at
most one per step (README, "Open boundaries": Cost).
"""

import numpy as np

from psph.boundaries.bodies import smooth_ramp
from psph.parallel.comm import allreduce_max, allreduce_sum
from psph.particles import Kind

# ties, in rows (dx): a row due within EMIT_TOL of t is emitted now, and a particle joins the fluid (or leaves
# it through an outflow face) only once it is TIE past the face. A time step can end exactly when a row
# reaches the face (t_end a multiple of dx / U); positions differ by round-off between rank counts, which
# must not decide it
EMIT_TOL = 1e-9
TIE = 1e-9


class Inflow:
    """One [[inflow]] buffer (scene.InflowSpec) on spacing dx."""

    def __init__(self, spec, dx):
        self.spec, self.dx = spec, dx
        self.axis = spec.axis
        self.velocity = np.asarray(spec.velocity, dtype=np.float64)
        self.speed = abs(self.velocity[self.axis])
        self.ramp = spec.ramp_time
        lower, upper = np.asarray(spec.lower, dtype=np.float64), np.asarray(spec.upper, dtype=np.float64)
        self.lower, self.upper = lower, upper
        # the upstream face: the lower one for a positive velocity
        self.sign = 1.0 if self.velocity[self.axis] > 0 else -1.0
        self.upstream = lower[self.axis] if self.sign > 0 else upper[self.axis]
        self.depth = upper[self.axis] - lower[self.axis]
        self.rows = max(1, int(round(self.depth / dx)))
        cross = []
        for a in range(len(lower)):
            if a == self.axis:
                continue
            n = max(1, int(round((upper[a] - lower[a]) / dx)))
            # centred in the buffer's cross-section at spacing dx
            first = 0.5 * (lower[a] + upper[a]) - 0.5 * (n - 1) * dx
            cross.append(first + dx * np.arange(n))
        grid = np.meshgrid(*cross, indexing="ij") if cross else []
        self.section = np.stack([g.ravel() for g in grid], axis=1) if cross else np.zeros((1, 0))
        self.profile = spec.profile
        self.factor = self.profile_factor(self._place(0.0))  # each column's speed over |U|
        # a non-reflecting buffer (spec.non_reflecting_time; OpenBoundaries.follow_sound): the speed it moves at
        # above the prescribed one (its acoustic part), the distance that has added to its travel, the pressure
        # level its characteristic holds, and when these were last brought up to date
        self.acoustic, self.offset, self.level, self.updated = 0.0, 0.0, None, 0.0

    def profile_factor(self, pos) -> np.ndarray:
        """u / U at positions `pos` by their transverse coordinates: 1 everywhere (a uniform profile), or
        prod_a 4 s_a (1 - s_a), s_a = (x_a - lower_a) / (upper_a - lower_a) over the axes across the buffer,
        1 at the section's centre and 0 at and beyond its sides (parabolic)."""
        factor = np.ones(len(pos))
        if self.profile == "parabolic":
            for a in range(len(self.lower)):
                if a != self.axis:
                    s = (pos[:, a] - self.lower[a]) / (self.upper[a] - self.lower[a])
                    factor *= np.clip(4.0 * s * (1.0 - s), 0.0, None)
        return factor

    def _place(self, xi) -> np.ndarray:
        """Positions of the cross-section at distances xi downstream of the upstream face (rows of xi)."""
        xi = np.atleast_1d(np.asarray(xi, dtype=np.float64))
        n_sec, dim = len(self.section), len(self.lower)
        pos = np.empty((len(xi) * n_sec, dim))
        other = [a for a in range(dim) if a != self.axis]
        pos[:, self.axis] = np.repeat(self.upstream + self.sign * xi, n_sec)
        if other:
            pos[:, other] = np.tile(self.section, (len(xi), 1))
        return pos

    def initial_positions(self) -> np.ndarray:
        return self._place((np.arange(self.rows) + 0.5) * self.dx)

    def travelled(self, t) -> float:
        """How far a buffer particle moving at |U| (every one, or the parabola's centre) has gone along the
        axis since t = 0: |U| t, or with ramp_time T, |U| S(t) of the smooth ramp
        (boundaries.bodies.smooth_ramp); a column of the profile has gone its factor times that. A
        non-reflecting buffer has gone `offset` further, its acoustic speed integrated over the steps."""
        return self.speed * smooth_ramp(t, self.ramp)[0] + self.offset

    def prescribed_speed(self, t) -> float:
        """|U| at time t, or |U| tau^2 (3 - 2 tau) during the ramp (the profile's centre)."""
        return self.speed * smooth_ramp(t, self.ramp)[1]

    def velocity_at(self, t, pos) -> np.ndarray:
        """The buffer's velocity at time t at positions `pos` (rows): U, or U tau^2 (3 - 2 tau) during the
        ramp, times the profile's factor there; a non-reflecting buffer's acoustic speed added."""
        along = np.zeros_like(self.velocity)
        along[self.axis] = self.sign * self.acoustic
        return np.outer(self.profile_factor(pos), self.velocity * smooth_ramp(t, self.ramp)[1] + along)

    def acceleration_at(self, t, pos) -> np.ndarray:
        """d/dt of velocity_at (zero without a ramp, and after it)."""
        return np.outer(self.profile_factor(pos), self.velocity * smooth_ramp(t, self.ramp)[2])

    def emitted(self, t) -> np.ndarray:
        """Rows each column (section point) has emitted since t = 0."""
        return np.floor(self.factor * self.travelled(t) / self.dx + EMIT_TOL).astype(np.int64)

    def rows_after(self, before, due, t) -> np.ndarray:
        """Positions at time t of the rows each column emitted after its row `before` up to its row `due`
        (per column, or one count for all; rows count from 1), in the order of the rows, then of the
        columns."""
        before, due = (np.broadcast_to(np.asarray(v, dtype=np.int64), self.factor.shape) for v in (before, due))
        counts = np.maximum(due - before, 0)
        column = np.repeat(np.arange(len(self.factor)), counts)
        m = np.repeat(before, counts) + 1 + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        order = np.lexsort((column, m))
        column, m = column[order], m[order]
        pos = np.empty((len(m), len(self.lower)))
        pos[:, self.axis] = self.upstream + self.sign * ((0.5 - m) * self.dx + self.factor[column] * self.travelled(t))
        other = [a for a in range(len(self.lower)) if a != self.axis]
        if other:
            pos[:, other] = self.section[column]
        return pos

    def in_section(self, pos) -> np.ndarray:
        """Mask of positions within the buffer's cross-section (any distance along its axis)."""
        mask = np.ones(len(pos), dtype=bool)
        for a in range(pos.shape[1]):
            if a != self.axis:
                mask &= (pos[:, a] > self.lower[a]) & (pos[:, a] < self.upper[a])
        return mask

    def holds(self, pos) -> np.ndarray:
        """Mask of positions within the buffer: in its cross-section, between its faces (TIE dx past them)."""
        xi = self.sign * (pos[:, self.axis] - self.upstream)
        return (xi >= -TIE * self.dx) & (xi <= self.depth + TIE * self.dx) & self.in_section(pos)

    def inside(self, pos) -> np.ndarray:
        """Mask of positions inside the buffer box (the fluid lattice leaves them out)."""
        return np.all((pos >= self.lower) & (pos <= self.upper), axis=1)


# an inflow buffer particle whose fluid neighbours weigh less than this (sum_j W_ij V_j; a full support
# weighs about 1, the buffer's face row about 1/2) takes rho0 for the rest (compute.sums.shepard_from_fluid):
# its density is continuous as fluid enters its support
INFLOW_WEIGHT_FLOOR = 0.1


def make_inflows(scene) -> list:
    return [Inflow(spec, scene.domain.dx) for spec in scene.inflow]


def prescribed_fields(scene, n, velocity) -> dict:
    """Fields of n new inflow particles moving at `velocity` (one, or a row each): rho0, its pressure, dx^d
    volumes and masses."""
    from psph.schemes.eos import make_eos

    d, rho0 = scene.domain, scene.physics.density
    vol = d.dx ** d.dimension
    return {"kind": np.full(n, Kind.INLET, dtype=np.int8), "volume": np.full(n, vol), "volume0": np.full(n, vol),
            "velocity": np.broadcast_to(velocity, (n, d.dimension)).copy(), "density": np.full(n, rho0),
            "mass": np.full(n, rho0 * vol),
            "pressure": np.full(n, float(make_eos(scene.physics).pressure(np.array([rho0]))[0]))}


def initial_inflow_particles(scene, comm, first_gid):
    """The buffers' particles at t = 0 (on rank 0) as arrays of fields, gids from first_gid on; None if the
    scene has no inflow."""
    if not scene.inflow:
        return None
    inflows = make_inflows(scene)
    pos = [f.initial_positions() if comm.rank == 0 else np.zeros((0, scene.domain.dimension)) for f in inflows]
    fields = [prescribed_fields(scene, len(x), f.velocity_at(0.0, x)) for f, x in zip(inflows, pos)]
    n = sum(len(x) for x in pos)
    out = {k: np.concatenate([f[k] for f in fields]) for k in fields[0]}
    out["position"] = np.concatenate(pos)
    out["gid"] = first_gid + np.arange(n, dtype=np.int64)
    return out


def describe_open(scene) -> list:
    """The scene's inflow buffers and outflow faces, in words (for `psph info` and the run log)."""
    lines = []
    for k, f in enumerate(make_inflows(scene)):
        parabolic = f.profile == "parabolic"
        lines.append(f"inflow[{k}]: buffer {tuple(f.lower)} - {tuple(f.upper)}, {f.rows} rows of "
                     f"{len(f.section)} particles at velocity {tuple(f.velocity)}"
                     + (f" at the centre of a parabolic profile (the columns' mean speed {f.factor.mean():.4g} "
                        "times it)" if parabolic else "")
                     + f", a row every {f.dx / f.speed:.4g} time units" + (" at speed U" if parabolic else "")
                     + (f" once reached, smoothly over ramp_time = {f.ramp:g}" if f.ramp else "")
                     + (f"; non-reflecting: its speed follows the sound leaving the fluid, against a pressure level "
                        f"relaxed over {f.spec.non_reflecting_time:g}" if f.spec.non_reflecting_time else ""))
    if scene.domain.outflow and scene.domain.outflow_buffer:
        lines.append(f"outflow faces {', '.join(scene.domain.outflow)}: fluid past them becomes a buffer one kernel "
                     "support deep, its density and velocity extrapolated from the fluid (Shepard average)"
                     + (f", its pressure relaxed to (1 - {scene.domain.outflow_relaxation:g}) times the fluid's"
                        if scene.domain.outflow_relaxation else "") + ", then is removed")
    elif scene.domain.outflow:
        lines.append(f"outflow faces {', '.join(scene.domain.outflow)}: fluid particles past them are removed")
    return lines


class NoOpenBoundaries:
    active = False

    def apply(self, system, t) -> dict:
        return {"joined": 0, "emitted": 0, "removed": 0}

    def start(self, system) -> int:
        return 0

    def extrapolate(self, system) -> None:
        pass

    def checkpoint_state(self):
        return None

    def restore(self, state) -> None:
        pass


class OpenBoundaries:
    """The scene's inflow buffers and outflow faces. `apply` after every time step (collective)."""

    active = True

    def __init__(self, scene, system):
        """Count the fluid's initial mass for the budget and the next gid. Collective."""
        self.scene = scene
        self.inflows = make_inflows(scene)
        self.outflow = scene.domain.outflow
        p = system.particles
        self.next_gid = int(allreduce_max(system.comm, int(p.owned("gid").max()) if p.n_owned else -1)) + 1
        self.emitted = [np.zeros(len(f.factor), dtype=np.int64) for f in self.inflows]  # rows per column
        self.totals = {"joined": 0, "emitted": 0, "removed": 0}
        # the fluid's mass budget: its mass at the start (or at a restart from a checkpoint without the budget),
        # and the mass of the particles that have joined it (inflow buffer; buffer particles carried back) or
        # left it (removed, or into the outflow buffer), each at the moment it did
        fluid = p.owned("kind") == Kind.FLUID
        self.mass = {"initial": allreduce_sum(system.comm, float(p.owned("mass")[fluid].sum())), "in": 0.0, "out": 0.0}
        self.buffer = scene.domain.outflow_buffer
        self.relaxation = scene.domain.outflow_relaxation
        from psph.schemes.eos import make_eos

        self.eos = make_eos(scene.physics)
        self.impedance = scene.physics.density * scene.physics.sound_speed
        for f in self.inflows:
            f.level = float(self.eos.pressure(np.array([scene.physics.density]))[0])

    def start(self, system) -> int:
        """At the start of a run (not a restart): fill the outflow buffers (fill_outflow_buffers), then set
        every buffer's fields from the fluid beside it (extrapolate), so that the first step sees the buffers
        as every later one does (an inflow buffer with `density = "extrapolated"` and no outflow buffer ran
        its first step at rho0: beside a hydrostatic layer the fluid moved back into it at 0.035 after 5 steps,
        0.017 with the extrapolation; an open-boundary audit). Returns how many particles the outflow buffers
        hold. Collective."""
        n = self.fill_outflow_buffers(system)
        self.extrapolate(system)
        return n

    def fill_outflow_buffers(self, system) -> int:
        """At the start of a run: the outflow buffers one kernel support deep already, as the fluid's mirror
        image across each outflow face (on a lattice, its rows continued), with the fluid's fields, which
        `extrapolate` then sets (start); returns how many particles they hold. Filled only by the fluid that crossed
        the face, a buffer cut the fluid's support there for the first support / U of the run, where the
        detection sees no free surface: a shifting law moved that fluid, and a uniform 1-D stream left at
        1.05 U (a dimensions audit). Only at a face the fluid reaches (within dx): a fill stopping short of it
        has a free surface there, which a buffer across the gap would hide. Gids: the mirrored particle's plus
        (k + 1) the first free one at face k (the same on any number of ranks; a particle near two faces is
        mirrored across each). Collective."""
        if not self.buffer:
            return 0
        p = system.particles
        pos, kind = p.owned("position"), p.owned("kind")
        support, dx = self.scene.domain.support, self.scene.domain.dx
        fluid = kind == Kind.FLUID
        added = []
        faces = system.domain.outflow
        for k, (axis, side) in enumerate(faces):
            face = system.domain.lower[axis] if side < 0 else system.domain.upper[axis]
            distance = np.abs(pos[:, axis] - face)
            gap = -allreduce_max(system.comm, -float(distance[fluid].min()) if fluid.any() else -np.inf)
            if not gap <= dx:
                continue
            near = fluid & (distance < support)
            rows = {name: arr[near].copy() for name, arr in p.owned_arrays().items()}
            rows["position"][:, axis] = 2.0 * face - rows["position"][:, axis]
            rows["kind"][:] = Kind.OUTLET
            rows["gid"] += (k + 1) * self.next_gid
            added.append(rows)
        if not added:
            return 0
        p.append_owned({name: np.concatenate([rows[name] for rows in added]) for name in added[0]})
        self.next_gid *= len(faces) + 1
        n = int(allreduce_sum(system.comm, sum(len(rows["gid"]) for rows in added)))
        system.rebuild()
        return n

    def apply(self, system, t) -> dict:
        """At time t: buffer particles past their downstream face join the fluid, rows due are emitted (on
        rank 0), fluid particles past an outflow face are removed; the lists are rebuilt if anything
        changed. Returns the global counts of this call. Collective."""
        p = system.particles
        pos, kind = p.owned("position"), p.owned("kind")
        self._check_backflow(system, pos, kind, t)
        self.follow_sound(system, t)
        for f in self.inflows:  # a rising velocity (ramp_time) is set, not left to the time integrator
            if f.ramp > 0.0 or f.spec.non_reflecting_time > 0.0:
                rows = (kind == Kind.INLET) & f.holds(pos)
                p.owned("velocity")[rows] = f.velocity_at(t, pos[rows])
        # a buffer particle that no buffer holds has passed its downstream face, however far: one moving more
        # than 2 dx a step once skipped the window (2 dx past the face) it had to be in to join, crossed the
        # domain as a buffer particle and left it unremoved (an audit: U dt = 3.2 dx, 64% of the mass flux)
        joined = kind == Kind.INLET
        for f in self.inflows:
            joined &= ~f.holds(pos)
        kind[joined] = Kind.FLUID
        entered = joined.copy()
        tie = TIE * self.scene.domain.dx
        if self.buffer:  # fluid past a face joins the buffer, which lets it go a kernel support further (and
            # buffer carried back inside by the extrapolated velocity is fluid again)
            past = system.domain.past_outflow(pos, tie)
            left = (kind == Kind.FLUID) & past
            back = (kind == Kind.OUTLET) & ~past
            entered |= back
            kind[left] = Kind.OUTLET
            kind[back] = Kind.FLUID
            removed = (kind == Kind.OUTLET) & (system.domain.past_outflow(pos, self.scene.domain.support + tie)
                                               | self._orphans(system))
        else:
            removed = left = (kind == Kind.FLUID) & system.domain.past_outflow(pos, tie)
        mass = p.owned("mass")
        new = []
        for k, f in enumerate(self.inflows):
            due = f.emitted(t)
            if (due > self.emitted[k]).any():
                x = f.rows_after(self.emitted[k], due, t)
                new.append((x, f.velocity_at(t, x)))
                self.emitted[k] = due
        n_new = sum(len(x) for x, _ in new)
        counts = allreduce_sum(system.comm, np.array([joined.sum(), removed.sum(), mass[entered].sum(),
                                                      mass[left].sum()]))
        out = {"joined": int(counts[0]), "emitted": n_new, "removed": int(counts[1])}
        self.mass["in"] += float(counts[2])
        self.mass["out"] += float(counts[3])
        if not (out["joined"] or out["emitted"] or out["removed"]):
            self.extrapolate(system)
            return out
        if out["removed"]:
            p.set_owned({name: arr[~removed] for name, arr in p.owned_arrays().items()})
        if n_new and system.comm.rank == 0:
            fields = [prescribed_fields(self.scene, len(x), v) for x, v in new]
            arrays = {k: np.concatenate([f[k] for f in fields]) for k in fields[0]}
            arrays["position"] = np.concatenate([x for x, _ in new])
            arrays["gid"] = self.next_gid + np.arange(n_new, dtype=np.int64)
            p.append_owned({k: v for k, v in arrays.items() if k in p}, fill={"body": -1})
        self.next_gid += n_new
        system.rebuild()
        self.extrapolate(system)
        for key in self.totals:
            self.totals[key] += out[key]
        return out

    def follow_sound(self, system, t) -> None:
        """At time t, after a step: each non-reflecting buffer (inflow.non_reflecting_time = T > 0) adds the
        distance its acoustic speed a moved it during the step to its travel (Inflow.offset), then takes a new
        a from the fluid beside its downstream face (within h of it, across its section; means over all
        ranks): with p and u that fluid's mean pressure and speed along the inflow, U(t) the prescribed
        speed and P the pressure level,

            P  <-  P + (p - P) (1 - exp(-dt / T))
            a   =  ((u - U) - (p - P) / (rho0 c0)) / 2,

        so that U + a = (J+ - J-) / (2 rho0 c0) for the outgoing characteristic J- = p - rho0 c0 u of that
        fluid and the incoming one J+ = P + rho0 c0 U (linear acoustics, one dimension along the axis; Poinsot
        and Lele's characteristic inflow, J. Comput. Phys. 101, 1992, with the pressure target relaxed). A
        sound wave running upstream (p' = -rho0 c0 u') leaves with the buffer at u and the fluid's pressure
        (its density extrapolated), where a velocity inlet reflects it. When the fluid is steady at P (changes
        much slower than T), u = U + a gives a = 0: the mean speed is U. The buffer never moves backwards (a >=
        -U). Rows are emitted and move on its travel, so they stay a lattice. Collective."""
        inlets = [f for f in self.inflows if f.spec.non_reflecting_time > 0.0]
        if not inlets:
            return
        p = system.particles
        pos, velocity = p.owned("position"), p.owned("velocity")
        fluid = p.owned("kind") == Kind.FLUID
        pressure = self.eos.pressure(p.owned("density"))
        # the fluid within h of the face: the upstream half of a pulse 5 dx wide came back 6.2% from a buffer
        # (T = 10) that read the fluid within h, 16% within 2 h (the band's mean lags the wave at the face),
        # 6.1% within 0.6 h (by hand, with the pulse of tests/boundaries/test_open.py)
        band = self.scene.domain.h
        sums = np.zeros((len(inlets), 3))
        for k, f in enumerate(inlets):
            xi = f.sign * (pos[:, f.axis] - f.upstream) - f.depth
            near = fluid & f.in_section(pos) & (xi > 0.0) & (xi < band)
            sums[k] = near.sum(), pressure[near].sum(), f.sign * velocity[near, f.axis].sum()
        sums = allreduce_sum(system.comm, sums)
        for f, (n, p_sum, u_sum) in zip(inlets, sums):
            dt, f.updated = t - f.updated, t
            f.offset += f.acoustic * dt
            if not n:  # no fluid beside the face (yet): the prescribed speed
                f.acoustic = 0.0
                continue
            u, p_mean, speed = u_sum / n, p_sum / n, f.prescribed_speed(t)
            f.level += (p_mean - f.level) * -np.expm1(-dt / f.spec.non_reflecting_time)
            f.acoustic = max(0.5 * ((u - speed) - (p_mean - f.level) / self.impedance), -speed)

    def _orphans(self, system) -> np.ndarray:
        """Owned outflow-buffer particles with no fluid particle within the neighbour lists' radius (a kernel
        support and the skin; the kinds this call changed refreshed first): no fluid sum reads them, and the
        extrapolation leaves them as they were, so gravity, which a buffer falls with (schemes.delta_ale),
        carried them on for ever (an open-boundary audit: the fill's deepest row, a support from a fluid at
        rest, fell through the floor and out of the domain; the run stopped at t = 0.46). The skin spares the
        rows a support away by round-off (a uniform jet's deepest, which a shifted fluid leaves just outside
        the support at the jet's sides). Collective."""
        p = system.particles
        system.refresh(["kind"])
        rows = np.flatnonzero(p.owned("kind") == Kind.OUTLET)
        orphan = np.zeros(p.n_owned, dtype=bool)
        if rows.size:
            ptr, kind, pos = system.nbr_ptr, p["kind"], p["position"]
            lengths = ptr[rows + 1] - ptr[rows]
            entries = np.repeat(ptr[rows] - np.cumsum(lengths) + lengths, lengths) + np.arange(lengths.sum())
            j, i = system.nbr_idx[entries], np.repeat(rows, lengths)
            near = (kind[j] == Kind.FLUID) & (((pos[j] - pos[i]) ** 2).sum(axis=1) < system.list_radius ** 2)
            held = np.bincount(np.repeat(np.arange(len(rows)), lengths), weights=near, minlength=len(rows)) > 0
            orphan[rows[~held]] = True
        return orphan

    def _check_backflow(self, system, pos, kind, t) -> None:
        """Stop (NumericalError, every rank) if fluid flowed back into an inflow buffer: a fluid particle in a
        buffer's cross-section more than dx/2 upstream of its downstream face. The buffer's rows move on at
        U through it, the two overlap, and the run went on to fail later on a volume or density at a place
        that named neither the inflow nor the backflow (an open-boundary audit: a channel driven against
        gravity, g = 3, its buffer at rho0, 40 fluid particles in the buffer by t = 0.79). The message counts
        them over all ranks and names the one of smallest gid, whatever the decomposition. Collective."""
        from psph.errors import NumericalError

        if not self.inflows:
            return
        fluid = kind == Kind.FLUID
        gid = system.particles.owned("gid")
        mine = []  # per inflow: (count, smallest gid, its position) on this rank
        for f in self.inflows:
            xi = f.sign * (pos[:, f.axis] - f.upstream)
            back = np.flatnonzero(fluid & f.in_section(pos) & (xi >= 0.0) & (xi < f.depth - 0.5 * f.dx))
            first = back[np.argmin(gid[back])] if len(back) else None
            mine.append((len(back), int(gid[first]), tuple(pos[first])) if first is not None else (0, -1, ()))
        found = system.comm.allgather(mine)
        for k, f in enumerate(self.inflows):
            hits = [rank[k] for rank in found if rank[k][0]]
            if not hits:
                continue
            count = sum(h[0] for h in hits)
            _, first, place = min(hits, key=lambda h: h[1])
            advice = (f'; inflow[{k}].density = "prescribed" holds the buffer at rho0, "extrapolated" lets its '
                      "pressure follow the fluid's" if f.spec.density == "prescribed" else "")
            error = NumericalError(
                f"fluid flowed back into inflow[{k}]'s buffer ({count} particle(s) more than dx/2 upstream of its "
                "downstream face): the flow needs a higher pressure at the inlet than the buffer gives"
                f"{advice}", step=system.where.get("step"), time=t, gid=first, position=np.array(place))
            error.collective = True  # every rank raises it (the same message): the run stops cleanly
            raise error

    def extrapolate(self, system) -> None:
        """Set the outflow buffer's density, pressure, mass and velocity from the fluid beside it (lists
        current), and those of an inflow buffer with `density = "extrapolated"` but its velocity: in `apply`,
        and again after a shifting that moves the fluid after `apply` (IIPS and its field update), so that the
        buffers continue the fluid the next step starts from. Collective."""
        extrapolated = [f for f in self.inflows if f.spec.density == "extrapolated"]
        if not self.buffer and not extrapolated:
            return
        from psph.compute.sums import shepard_from_fluid

        p = system.particles
        # the fluid's halo copies as the step (and a field update after IIPS: its volumes too) left them, and the
        # kinds this step changed (fluid into buffer)
        system.refresh(["kind", "density", "velocity", "volume"])
        rows = np.flatnonzero(p.owned("kind") == Kind.OUTLET)
        shepard_from_fluid(p["position"], p["volume"], p["kind"], rows, system.nbr_ptr, system.nbr_idx,
                           system.kernel.params, p["density"], p["velocity"], 0.0, 0.0)
        if self.relaxation:  # p_buffer = (1 - a) p_fluid, through the equation of state (linear or Tait)
            rho = p.owned("density")
            rho[rows] = self.eos.density((1.0 - self.relaxation) * self.eos.pressure(rho[rows]))
        if extrapolated:  # the inflow buffers' density only: their velocity stays prescribed
            held = np.zeros(p.n_owned, dtype=bool)
            for f in extrapolated:
                held |= f.holds(p.owned("position"))
            inflow = np.flatnonzero(held & (p.owned("kind") == Kind.INLET))
            shepard_from_fluid(p["position"], p["volume"], p["kind"], inflow, system.nbr_ptr, system.nbr_idx,
                               system.kernel.params, p["density"], np.zeros_like(p["velocity"]),
                               INFLOW_WEIGHT_FLOOR, self.scene.physics.density)
            rows = np.concatenate([rows, inflow])
        p.owned("pressure")[rows] = self.eos.pressure(p.owned("density")[rows])
        p.owned("mass")[rows] = p.owned("density")[rows] * p.owned("volume")[rows]
        system.refresh(["density", "pressure", "mass", "velocity"])

    def budget(self, total_mass) -> dict:
        """history.csv's mass budget from the fluid's `total_mass` now: the mass that has entered and left
        the fluid, and the error of the balance total_mass - initial - in + out relative to the initial mass
        (to the mass that came in, for a fluid that starts empty), zero to round-off when the scheme moves no
        mass between the fluid and the buffers' particles; and each non-reflecting buffer's speed along its
        axis, its acoustic part included (inflow_speed_k, k its place in [[inflow]])."""
        m = self.mass
        scale = m["initial"] or m["in"] or 1.0
        out = {"mass_in": m["in"], "mass_out": m["out"],
               "mass_balance_error": (total_mass - m["initial"] - m["in"] + m["out"]) / scale}
        for k, f in enumerate(self.inflows):  # a non-reflecting buffer's speed (its acoustic part included)
            if f.spec.non_reflecting_time > 0.0:
                out[f"inflow_speed_{k}"] = f.prescribed_speed(f.updated) + f.acoustic
        return out

    def checkpoint_state(self) -> dict:
        return {"next_gid": self.next_gid, "emitted": [e.tolist() for e in self.emitted], "totals": dict(self.totals),
                "mass": dict(self.mass),
                "acoustic": [[f.acoustic, f.offset, f.level, f.updated] for f in self.inflows]}

    def restore(self, state) -> None:
        if state is None:  # a checkpoint written before the scene had open boundaries (the budget: as above)
            return
        self.next_gid = int(state["next_gid"])
        # (a checkpoint of before profiles holds one count per buffer: every column's)
        self.emitted = [np.broadcast_to(np.asarray(e, dtype=np.int64), f.factor.shape).copy()
                        for e, f in zip(state["emitted"], self.inflows)]
        self.totals = {k: int(v) for k, v in state["totals"].items()}
        if "mass" in state:  # else (a checkpoint written before the budget) it starts from the restart's mass
            self.mass = {k: float(v) for k, v in state["mass"].items()}
        for f, values in zip(self.inflows, state.get("acoustic", ())):  # (none before non-reflecting buffers)
            f.acoustic, f.offset, f.level, f.updated = (float(v) for v in values)


def make_open_boundaries(scene, system):
    """The scene's open boundaries, or a no-op without inflow or outflow. Collective."""
    if scene.inflow or scene.domain.outflow:
        return OpenBoundaries(scene, system)
    return NoOpenBoundaries()
