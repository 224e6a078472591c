"""The delta-ALE-SPH scheme and its two simplified variants (seed 001 = Antuono et al. 2021).

    delta_ale               eq. 13-15: density, mass and momentum m u evolve; V = m / rho
    delta_ale_const_mass    eq. 23 (the consistent delta+-SPH): density and velocity evolve; V = m0 / rho
    delta_ale_const_volume  eq. 25: density and velocity evolve; operators use V0; m = V0 rho

with the equation of state of psph.schemes.eos, viscosity mu = rho0 U L / Re through the pi_ij operator
(eq. 11, K = 2(d+2); or Morris' with physics.viscosity = "morris"), gravity, the diffusive terms D^rho
(delta = 0.1) and D^m (eq. 14), the tensile switch (p_j - p_i where p_i < 0 outside the free-surface
region: seed 004 eq. 3) and the shifting velocity du of an explicit law
(psph.shifting.velocity) with its du-terms (eq. 12); without shifting those terms are skipped. Near a free
surface the shifting velocity is restricted by psph.boundaries.free_surface (thesis eq. 6.29). Inflow and
outflow-buffer particles (psph.boundaries.open) take part in the sums as fluid but get no rates: their
fields are prescribed there.
The kernels are in psph.compute.fluid.
"""

import numpy as np

from psph.boundaries.clone import make_walls
from psph.boundaries.free_surface import FreeSurface, make_free_surface
from psph.boundaries.open import make_inflows
from psph.compute.fluid import (
    PairCache,
    add_uniform_acceleration,
    delta_ale_rhs,
    fluid_momentum_totals,
    renormalised_gradient,
)
from psph.parallel.comm import allreduce_sum
from psph.particles import FieldSpec, Kind
from psph.profiling import phase
from psph.schemes.eos import make_eos
from psph.shifting.velocity import make_velocity_shift

VARIANTS = {"delta_ale": 0, "delta_ale_const_mass": 1, "delta_ale_const_volume": 2}


class DeltaALE:
    # a shifting law's corrected grad C from the renormalised gradient's pass (False: the law's own pass,
    # for the tests that compare the two)
    fuse_grad_c = True

    def __init__(self, scene):
        phys = scene.physics
        self.name = phys.scheme
        self.variant = VARIANTS.get(phys.scheme, 0)  # riemann_ale: V, m and m u evolve, as in variant 0
        self.wall_variant = self.variant  # the wall kernels' (psph.compute.walls)
        self.c0, self.rho0 = phys.sound_speed, phys.density
        self.nu = phys.kinematic_viscosity(scene.domain)
        self.mu = self.rho0 * self.nu
        self.delta, self.delta_m = phys.delta, phys.delta_m
        # D^rho or D^m act (eq. 14); a term reads the density gradient (D^rho's only): without it (standard
        # SPH) it is neither computed nor sent (the Riemann scheme's reconstruction always reads it)
        self.diffusive = self.delta > 0.0 or (self.variant == 0 and self.delta_m > 0.0)
        self.reads_grad_rho = self.delta > 0.0
        dim = scene.domain.dimension
        self.gravity = np.zeros(dim) if not phys.gravity else np.asarray(phys.gravity, dtype=np.float64)
        self.tensile = phys.tensile_switch
        self.morris = phys.viscosity == "morris"
        self.free_stream = np.asarray(phys.free_stream, dtype=np.float64) if phys.free_stream else None
        self.free_stream_ramp = phys.free_stream_ramp
        self.eos = make_eos(phys)
        self.shift = make_velocity_shift(scene)
        self.surface = make_free_surface(scene)
        # seed 004 eq. 3: the tensile switch stays off in the free-surface region (the surface particles and
        # their neighbours); seed 001 section 6.3: the diffusive terms stay off where lambda is small. A scene
        # with a free surface detects it at every step for them, even without shifting
        surface = scene.surface_switches()
        self.lambda_diffusion = scene.free_surface.lambda_diffusion if surface else 0.0
        # in the free-surface region a wall pushes and never pulls (physics.wall_adhesion = false)
        self.no_pull = surface and scene.has_clone_walls() and not phys.wall_adhesion
        self.step_surface = None
        if scene.switches_free_surface():
            self.step_surface = self.surface if self.surface.active else FreeSurface(scene.free_surface)
        self.pairs = PairCache()  # the support's pairs, from renormalised_gradient to delta_ale_rhs
        # rows of Kind.INLET and OUTLET keep the fields psph.boundaries.open prescribes
        self.prescribed = bool(scene.inflow) or scene.domain.outflow_buffer
        self.ramps = [f for f in make_inflows(scene) if f.ramp > 0.0]  # buffers whose velocity rises (ramp_time)
        self.walls = make_walls(scene)
        # with ghost walls the scene has no shifting near a free surface (schema): only the switches' detection
        # runs, and it sees the fluid along them with their images
        if self.walls.ghost is not None and self.step_surface is not None:
            self.step_surface.ghost_walls = self.walls

    # ------------------------------------------------------------ description
    def describe(self) -> list:
        names = {0: "delta-ALE-SPH (seed 001 eq. 13-15)", 1: "delta-ALE-SPH with constant masses (eq. 23)",
                 2: "delta-ALE-SPH with constant volumes (eq. 25)"}
        lines = [f"scheme: {names[self.variant]}",
                 f"equation of state: {self.eos.name}, c0 = {self.c0:g}, rho0 = {self.rho0:g}",
                 f"viscosity: {'Morris et al. (1997)' if self.morris else 'pi_ij (eq. 11)'} operator, "
                 f"nu = {self.nu:g}",
                 f"density diffusion D^rho, delta = {self.delta:g} (eq. 14)" if self.delta else
                 "density diffusion off"]
        if self.variant == 0:
            lines.append(f"mass diffusion D^m, delta = {self.delta_m:g}" if self.delta_m else "mass diffusion off")
        if np.any(self.gravity):
            lines.append(f"gravity {tuple(self.gravity)}")
        if self.free_stream is not None:
            lines.append(f"free stream {tuple(self.free_stream)} reached at t = {self.free_stream_ramp:g}: a "
                         "uniform force sets the fluid's total momentum (periodic wind tunnel)")
        if self.tensile:
            lines.append("tensile-instability switch (p_j - p_i where p_i < 0" + (
                ", off in the free-surface region: seed 004 eq. 3, the surface detected every step)"
                if self.step_surface is not None else ")"))
        if self.no_pull:
            lines.append("clone walls in the free-surface region: a solid neighbour's pressure max(p_j, 0) where "
                         "the wall would pull the fluid, a wall that pushes and never pulls "
                         "(physics.wall_adhesion = false)")
        if self.lambda_diffusion > 0.0:
            lines.append(f"diffusive terms only between fluid particles with lambda > {self.lambda_diffusion:g} "
                         "(seed 001 section 6.3: none in thin jets and drops)")
        lines.append(self.shift.describe())
        return lines + self.walls.describe()

    # ----------------------------------------------------------------- fields
    def field_specs(self):
        specs = [FieldSpec("velocity", ("d",)), FieldSpec("density"), FieldSpec("mass"), FieldSpec("pressure"),
                 FieldSpec("grad_rho", ("d",)), FieldSpec("volume0")]
        surface = self.step_surface if self.step_surface is not None else self.surface
        return specs + list(self.shift.fields) + list(surface.fields) + list(self.walls.fields)

    def halo_fields(self):
        # volume0: read at neighbours by the fictitious pressure (eq. 7.3) and by IIPS + NFTS (copied at
        # rebuilds only: it never changes)
        names = ["position", "gid", "kind", "volume", "volume0", "density", "mass", "velocity", "pressure",
                 "grad_rho"]
        return names + list(self.walls.halo_fields) + list(self.shift.halo_fields)

    def initialize(self, system, t=0.0, fresh=True):
        """Density from the initial pressure (or rho0), masses from volumes, the volumes V0; solids placed
        at time t. A restart (fresh=False) keeps the fields it read. Collective."""
        p = system.particles
        for spec in self.field_specs():
            p.add_field(spec)
        if fresh:
            self._initial_fields(p)
        if not fresh:
            self.walls.link_nodes(system)
        self.walls.place(system, t)
        for name in self.halo_fields():
            system.add_halo_field(name)
        system.refresh(self.halo_fields())

    def _initial_fields(self, p):
        if "pressure" in p:
            p.owned("density")[:] = self.eos.density(p.owned("pressure"))
        else:
            p.owned("density")[:] = self.rho0
        p.owned("mass")[:] = p.owned("density") * p.owned("volume")
        p.owned("volume0")[:] = p.owned("volume")
        p.owned("pressure")[:] = self.eos.pressure(p.owned("density"))
        if "transport_velocity" in p:
            p.owned("transport_velocity")[:] = p.owned("velocity")
        if self.walls.active:
            solid = (p.owned("kind") == Kind.WALL) | (p.owned("kind") == Kind.BODY)
            p.owned("density")[solid] = self.rho0
            p.owned("mass")[solid] = self.rho0 * p.owned("volume")[solid]
            p.owned("pressure")[solid] = 0.0

    def initial_volume(self, system):
        return system.particles["volume0"]

    # ------------------------------------------------------------------ state
    def state(self, system) -> dict:
        """Copies of the integrated variables of the owned particles."""
        p = system.particles
        out = {"position": p.owned("position").copy(), "density": p.owned("density").copy()}
        if self.variant == 0:
            out["mass"] = p.owned("mass").copy()
            out["momentum"] = p.owned("mass")[:, None] * p.owned("velocity")
        else:
            out["velocity"] = p.owned("velocity").copy()
        return out

    def set_state(self, system, state, refresh_positions=True) -> None:
        """Write the integrated variables back and derive V, m, u, p (owned); refresh halo positions."""
        p = system.particles
        p.owned("position")[:] = state["position"]
        rho = p.owned("density")
        rho[:] = state["density"]
        if self.variant == 0:
            p.owned("mass")[:] = state["mass"]
            p.owned("velocity")[:] = state["momentum"] / state["mass"][:, None]
            p.owned("volume")[:] = state["mass"] / rho
        else:
            p.owned("velocity")[:] = state["velocity"]
            if self.variant == 1:
                p.owned("volume")[:] = p.owned("mass") / rho
            else:
                p.owned("mass")[:] = p.owned("volume0") * rho
        p.owned("pressure")[:] = self.eos.pressure(rho)
        if refresh_positions:
            system.refresh(["position"])

    # -------------------------------------------------------------------- rhs
    def detect_surface(self, system) -> None:
        """The step's free-surface flags and lambda, where the shifting law, the tensile switch or the
        diffusion switch (free_surface.lambda_diffusion) needs them. Collective."""
        if self.shift.active and self.surface.active:
            self.surface.detect(system)
        elif self.step_surface is not None:
            self.step_surface.detect(system)
        if self.lambda_diffusion > 0.0:  # read on the halo rows too
            system.refresh(["surface_lambda"])

    def tensile_rows(self, system) -> np.ndarray:
        """1 where the tensile switch may act (p_i < 0 then uses p_j - p_i), 0 where it is off or in the
        free-surface region (seed 004 eq. 3), per local particle."""
        p = system.particles
        if not self.tensile:
            return np.zeros(p.n_local, dtype=np.int8)
        if self.step_surface is None:
            return np.ones(p.n_local, dtype=np.int8)
        return (p["free_surface"] == 0).astype(np.int8)

    def no_pull_rows(self, system) -> np.ndarray:
        """1 where no wall pair may pull the particle towards the wall (the free-surface region, without
        physics.wall_adhesion), 0 elsewhere, per local particle."""
        p = system.particles
        if not self.no_pull:
            return np.zeros(p.n_local, dtype=np.int8)
        return (p["free_surface"] != 0).astype(np.int8)

    def diffusion_rows(self, system):
        """1 where a particle takes part in the diffusive terms (lambda above free_surface.lambda_diffusion,
        seed 001 section 6.3), per local particle; True (all) without the switch."""
        if not self.diffusive:
            return False
        if self.lambda_diffusion <= 0.0:
            return True
        return (system.particles["surface_lambda"] > self.lambda_diffusion).astype(np.int8)

    def place_walls(self, system, t) -> bool:
        """The solids' velocities, normals and accelerations at the stage time t, halo included; whether the
        scene has walls (the kernels' dispatch: solid neighbours or none). Collective."""
        walls = self.walls.active
        self.walls.place(system, t, positions=False)
        if walls:  # (a halo exchange: none without solids)
            with phase("walls"):
                system.refresh(["normal", "wall_accel", "wall_velocity"])
        return walls

    def rhs(self, system, t, dt) -> dict:
        """d(state)/dt at the current state (owned rows). Collective (halo exchanges)."""
        p = system.particles
        walls = self.place_walls(system, t)
        system.refresh(["density", "mass", "velocity", "volume", "pressure"])
        self.shift_and_density_gradient(system, t, dt, fluid_only=walls)
        du = self.shift.du(p)
        if self.reads_grad_rho:
            system.refresh(["grad_rho"])
        kp = system.kernel.params
        n, d = p.n_owned, p.dim
        d_rho = np.zeros(n)
        d_mass = np.zeros(n)
        d_mom = np.zeros((n, d))
        delta_ale_rhs(p["position"], p["volume"], p["density"], p["mass"], p["velocity"], du, p["pressure"],
                      p["grad_rho"], self.pairs, kp, self.c0, self.delta, self.delta_m,
                      self.mu, self.gravity, self.variant, self.shift.active, self.tensile_rows(system), p["kind"],
                      walls, d_rho, d_mass, d_mom, morris=self.morris, diffusive=self.diffusion_rows(system))
        self.walls.add(system, self, t, d_rho, d_mom)
        if self.free_stream is not None:
            self._drive_free_stream(system, t, d_mom)
        if self.prescribed:  # open-boundary particles move at their prescribed velocity, fields unchanged
            kind = p.owned("kind")
            fixed = (kind == Kind.INLET) | (kind == Kind.OUTLET)
            d_rho[fixed], d_mass[fixed], d_mom[fixed] = 0.0, 0.0, 0.0
            self._fall_with_gravity(p, kind == Kind.OUTLET, d_mom)
            self._ramp_inflows(p, kind, t, d_mom)
        out = {"position": self.shift.transport(p), "density": d_rho}
        if self.variant == 0:
            out["mass"] = d_mass
            out["momentum"] = d_mom
        else:
            out["velocity"] = d_mom
        return out

    def _ramp_inflows(self, p, kind, t, d_mom) -> None:
        """An inflow buffer with a ramp_time accelerates as its prescribed velocity rises (Inflow.acceleration_at,
        at the stage's time t), so that within a step its particles follow the ramp (psph.boundaries.open sets
        the velocity itself after every step)."""
        for f in self.ramps:
            rows = (kind == Kind.INLET) & f.holds(p.owned("position"))
            d_mom[rows] = (f.acceleration_at(t, p.owned("position")[rows])
                           * (p.owned("mass")[rows, None] if self.variant == 0 else 1.0))

    def _fall_with_gravity(self, p, outlet, d_mom) -> None:
        """An outflow buffer's rows (`outlet`, owned) accelerate with gravity within a step: their state is the
        fluid's extrapolated with zero gradient (psph.boundaries.open), so no pressure or viscous force acts
        on them, and the momentum equation leaves g. At rest within the step, they lagged the fluid leaving
        through them by g dt, and the relative velocity compressed the fluid at a face it leaves through and
        expanded it at one it moves away from: a slab falling through two buffered faces built a pressure
        gradient that held it at 0.95 g at the default time step (first order in dt: 0.968 g at 5/8 of it,
        0.984 g at 5/16)."""
        if np.any(self.gravity) and outlet.any():
            d_mom[outlet] = self.gravity * (p.owned("mass")[outlet, None] if self.variant == 0 else 1.0)

    def shift_and_density_gradient(self, system, t, dt, fluid_only) -> None:
        """The shifting velocity (owned rows, then their halo copies) and the renormalised density gradient
        with the pair cache (owned rows; the caller refreshes the halo), the gradient only where a term reads
        it (self.reads_grad_rho). A law built on the corrected grad C
        gets it from the gradient's own pass over the lists (compute.fluid.renormalised_gradient), which
        spares a second pass. Collective."""
        p, law = system.particles, self.shift
        grad_c = None
        if law.grad_c_weights is not None and self.fuse_grad_c:
            grad_c = (*law.grad_c_weights, law.reference_w(system), np.zeros((p.n_owned, p.dim)))
        renormalised_gradient(p["position"], p["volume"], p["density"], system.nbr_ptr, system.nbr_idx,
                              system.kernel.params, p["kind"], fluid_only, p["grad_rho"], self.pairs, grad_c=grad_c,
                              gradient=self.reads_grad_rho)
        if law.active:
            law.velocity(system, self, dt, grad=None if grad_c is None else grad_c[3])
            self.surface.restrict(system, p.owned("shift_velocity"), self.walls, t)
            system.refresh(["shift_velocity"])

    def free_stream_velocity(self, t):
        """The mean velocity U(t) = U (t/T - sin(2 pi t/T) / (2 pi)) up to T, then U, and its derivative."""
        T = self.free_stream_ramp
        if t >= T:
            return self.free_stream.copy(), np.zeros_like(self.free_stream)
        return (self.free_stream * (t / T - np.sin(2.0 * np.pi * t / T) / (2.0 * np.pi)),
                self.free_stream * (1.0 - np.cos(2.0 * np.pi * t / T)) / T)

    def _drive_free_stream(self, system, t, d_mom):
        """Add the uniform acceleration g that makes the fluid's mean velocity P/M follow U(t):
        g = dU/dt - (sum_i d(m_i u_i)/dt) / M + (U(t) - P/M) / T, whatever the walls and bodies took
        (physics.free_stream, T its ramp time). The first two terms hold the total momentum at M U(t) to the
        time integrator's error where the masses are constant (delta_ale, delta_ale_const_mass); the last
        relaxes what they leave over T: the changing masses of delta_ale_const_volume and the momentum the
        IIPS field updates move between steps. Collective."""
        p = system.particles
        kind, m, d = p.owned("kind"), p.owned("mass"), p.dim
        local = np.empty(2 * d + 1)
        fluid_momentum_totals(kind, m, p.owned("velocity"), d_mom, self.variant == 0, local)
        total = allreduce_sum(system.comm, local)
        mass = total[-1]
        target, slope = self.free_stream_velocity(t)
        g = slope - total[:d] / mass + (target - total[d:2 * d] / mass) / self.free_stream_ramp
        add_uniform_acceleration(kind, m, g, self.variant == 0, d_mom)

    def end_step(self, system, dt):
        self.shift.end_step(system, self, dt)

    def max_speeds(self, system) -> np.ndarray:
        """[largest |u + du|, largest signal speed c_i + |u_i + du_i|] of the owned particles (local): the
        transport speed the neighbour lists must hold, and the CFL condition's (thesis eq. 5.52, with each
        particle's sound speed: c0 with the linear equation of state, c0 (rho / rho0)^3 in the fluid with
        Tait; a Riemann audit found c0 taken there: a time step 33% longer than eq. 5.52's at the default 10%
        density limit)."""
        p = system.particles
        v = self.shift.transport(p)
        speed = np.sqrt((v * v).sum(axis=1))
        vmax = float(speed.max()) if len(v) else 0.0
        signal = self.c0 + vmax
        if self.eos.name == "tait":
            fluid = p.owned("kind") == Kind.FLUID
            if fluid.any():  # (a NaN density, which the state's checks name, is passed over by max)
                signal = max(signal, float((self.eos.sound_speed(p.owned("density")[fluid]) + speed[fluid]).max()))
        return np.array([vmax, signal])
