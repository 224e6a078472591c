"""Explicit shifting laws used inside the fluid schemes: each gives a shifting velocity du per particle,
added to the fluid velocity as the transport velocity u + du (seed 001 eq. 10; the ALE terms in du keep
the scheme consistent). Laws defined as displacements (Lind, Skillen: dx per time step) are applied as
du = dx / dt.

    none        du = 0 (a Lagrangian scheme; the du-terms are skipped)
    delta_plus  seed 001 eq. 16-17 (Sun et al.):  du* = -Ma (2h) c0 grad C^, R = 0.2, n = 4;
                |du| <= U_max / 2
    lind        thesis eq. 6.15-6.16 (Lind et al. 2012): dx = -D grad C^, D = `shifting.lind_diffusion` h^2 (eq.
                6.16 prints 0.5 h^2), |du| <= U_max / 2; the correction's b = 0.2, n = 4 are not in eq. 6.15-6.16
                (the thesis: "suggested in Monaghan 2000"), as in delta_plus. Two departures from eq. 6.16,
                which is written for ISPH, whose time step follows the flow (dt ~ 0.1 h / U): (1) applied
                once per step, the law is the explicit iteration of eq. 6.13 on grad C^, whose short waves grow
                above D = 0.24 / 0.33 / 0.38 h^2 in 1-/2-/3-D with Wendland C6 at h/dx = 2
                (psph.shifting.explicit.stability_limit with the weights; a dimensions audit: at 0.4 h^2, the
                explicit iteration's default, which this law took, a 1-D stream through an outflow sped up to
                1.12 U), so its default is 0.2 h^2; (2) its
                cap |dx| <= 0.2 h, |du| <= 0.2 h / dt, is ~c0 at a weakly compressible step (dt = 0.2 h / c0),
                and the time step, which reads |u + du|, then shrank at every step that a particle was capped
                until the run stopped (an audit: Taylor-Green 16 x 16 from the lattice, |du| = 6.8 c0 and dt
                6 times shorter at step 46, the density out of range at step 49). The cap is delta_plus's.
    skillen     thesis eq. 6.18 (Skillen et al. 2013): dx = -A h |u_i| dt grad C, A = `shifting.skillen_a`
                (the thesis gives no value for A; psph's default is 2)
    oger        thesis eq. 6.32 (Oger et al. 2016): du = -U_char 2 dx grad C, U_char = Ma c0 = U_max,
                |du| <= 0.25 |u_i|
    neuhauser   thesis eq. 6.33-6.35 with the particle-shifting coefficient P_S (eq. 7.1), or the fictitious
                pressure P^F (eq. 7.4) when `shifting.fictitious_pressure`: du = dt (dv0/dt)_smooth,
                p_ref = rho0 c0^2 / gamma (gamma = 7), alpha = 0.1; v0 of the previous step in the
                upwind and smoothing terms.
"""

import numpy as np

from psph.compute.eos import TAIT_GAMMA
from psph.compute.shift_velocity import corrected_grad_c, limit_magnitude, neuhauser_acceleration
from psph.diagnostics import fluid_mask
from psph.particles import FieldSpec

# the key that scales an uncapped explicit shifting law's velocity (delta+ and Lind's are capped at U/2, and
# Neuhauser's P^F reads no P_S)
STRENGTH_KEYS = {"skillen": "skillen_a", "neuhauser": "neuhauser_ps"}


def strength_key(spec) -> str:
    """The explicit shifting law's strength key and value ("shifting.skillen_a = 100") of `spec`, the scene's
    shifting section, or "" without such a law."""
    key = None if spec.method == "neuhauser" and spec.fictitious_pressure else STRENGTH_KEYS.get(spec.method)
    return f"shifting.{key} = {getattr(spec, key):g}" if key else ""


def strength_advice(spec) -> str:
    """For the message of a particle driven at several times the reference velocity: the law's strength key
    (strength_key), which can drive it that fast (an explicit-shifting audit: skillen_a = 100 and
    neuhauser_ps = 1000 stopped in a few steps naming no shifting key, the second advising a larger skin)."""
    key = strength_key(spec)
    return f" (shifting.method = {spec.method}: a law too strong, {key}, does that too)" if key else ""

SHIFT_VELOCITY = FieldSpec("shift_velocity", ("d",))


class VelocityShift:
    """Base, and no law (du = 0): a law's `velocity(system, scheme, dt, grad)` fills the owned rows of field
    'shift_velocity'; the scheme reads it through `du` and `transport`, which without a law are the velocity
    (and no field exists, none is sent).

    A law built on the corrected grad C (compute.shift_velocity.corrected_grad_c) names its (coeff, power) in
    `grad_c_weights`; the scheme may then compute that grad C in its own pass over the lists and hand it
    over as `grad` (the fluid part only: the law adds the ghost walls' images)."""

    name = "none"
    active = False  # (the kernels' dispatch: du-terms or none)
    fields = ()  # the fields it adds
    halo_fields = ()  # those of them the neighbours read
    grad_c_weights = None

    def __init__(self, scene=None):
        self.dx = scene.domain.dx if scene is not None else None

    def velocity(self, system, scheme, dt, grad=None):
        return None

    def du(self, p) -> np.ndarray:
        """du of the local rows, for the kernels' du-terms (without a law: the velocity, which they skip)."""
        return p["velocity"]

    def transport(self, p, owned=True, velocity=None) -> np.ndarray:
        """The transport velocity u + du (seed 001 eq. 10) of the owned (else the local) rows, a new array;
        `velocity`: u there if not the field's (a kinematic run's frozen field)."""
        rows = p.owned if owned else p.__getitem__
        return (rows("velocity") if velocity is None else velocity) + self._du_rows(rows)

    def _du_rows(self, rows):
        return 0.0

    def reference_w(self, system):
        """W(dx), the reference of the corrected grad C's weights."""
        return float(system.kernel.value(np.array([self.dx]))[0])

    def end_step(self, system, scheme, dt):
        """Called after a completed time step (laws with memory update it here)."""

    def describe(self) -> str:
        return "shifting velocity in the scheme: none (v0 = v, Lagrangian particles; no du terms)"


class NoVelocityShift(VelocityShift):
    pass


class ShiftingLaw(VelocityShift):
    """An explicit law: it adds and sends the field 'shift_velocity' (and its own `fields`)."""

    active = True
    fields = (SHIFT_VELOCITY,)
    halo_fields = ("shift_velocity",)

    def du(self, p) -> np.ndarray:
        return p["shift_velocity"]

    def _du_rows(self, rows):
        return rows("shift_velocity")


def _grad_c_hat(law, system, scheme, grad):
    """grad C corrected with [1 + coeff (W_ij / W(dx))^power] (law.grad_c_weights; coeff = 0: plain grad C),
    the ghost walls' images included; `grad`: its particles' part, if the scheme computed it already."""
    p, k = system.particles, system.kernel
    coeff, power = law.grad_c_weights
    w_ref = law.reference_w(system)
    out = grad
    if out is None:
        out = np.zeros((p.n_owned, p.dim))
        corrected_grad_c(p["position"], p["volume"], system.nbr_ptr, system.nbr_idx, k.params, coeff, power,
                         w_ref, out)
    scheme.walls.add_ghost_grad_c(system, coeff, power, w_ref, out)
    return out


class DeltaPlus(ShiftingLaw):
    name = "delta_plus"

    def __init__(self, scene):
        super().__init__(scene)
        self.coeff, self.power = scene.shifting.delta_plus_r, scene.shifting.delta_plus_n
        self.grad_c_weights = (self.coeff, self.power)
        self.u_max = scene.physics.reference_velocity

    def velocity(self, system, scheme, dt, grad=None):
        """du* = -Ma (2h) c0 grad C^ (seed 001 eq. 16-17), |du| <= U_max / 2. Local."""
        grad = _grad_c_hat(self, system, scheme, grad)
        raw = -self.u_max * 2.0 * system.kernel.h * grad  # Ma (2h) c0 = U_max 2h
        out = system.particles.owned("shift_velocity")
        limit_magnitude(raw, np.full(len(raw), 0.5 * self.u_max), out)
        out *= fluid_mask(system)[:, None]

    def describe(self):
        return (f"shifting: delta-plus velocity du = -Ma 2h c0 grad C^ (R = {self.coeff:g}, n = {self.power:g}), "
                f"|du| <= U_max/2 (seed 001 eq. 16-17)")


class Lind(ShiftingLaw):
    name = "lind"
    grad_c_weights = (0.2, 4.0)

    def __init__(self, scene):
        super().__init__(scene)
        self.d = scene.shifting.lind_diffusion
        self.u_max = scene.physics.reference_velocity

    def velocity(self, system, scheme, dt, grad=None):
        """du = dx / dt, dx = -D grad C^ (thesis eq. 6.15-6.16), |du| <= U_max / 2. Local."""
        h = system.kernel.h
        grad = _grad_c_hat(self, system, scheme, grad)
        raw = -self.d * h * h * grad / dt
        out = system.particles.owned("shift_velocity")
        limit_magnitude(raw, np.full(len(raw), 0.5 * self.u_max), out)
        out *= fluid_mask(system)[:, None]

    def describe(self):
        return (f"shifting: Lind (Fickian) dx = -{self.d:g} h^2 grad C^ per step, |du| <= U_max/2 (thesis eq. "
                "6.15-6.16; cap as delta_plus')")


class Skillen(ShiftingLaw):
    name = "skillen"
    grad_c_weights = (0.0, 1.0)

    def __init__(self, scene):
        super().__init__(scene)
        self.a = scene.shifting.skillen_a

    def velocity(self, system, scheme, dt, grad=None):
        """du = dx / dt, dx = -A h |u_i| dt grad C (thesis eq. 6.18). Local."""
        p = system.particles
        grad = _grad_c_hat(self, system, scheme, grad)
        speed = np.sqrt((p.owned("velocity") ** 2).sum(axis=1))[:, None]
        p.owned("shift_velocity")[:] = -self.a * system.kernel.h * speed * grad * fluid_mask(system)[:, None]

    def describe(self):
        return f"shifting: Skillen dx = -A h |u| dt grad C, A = {self.a:g} (thesis eq. 6.18)"


class Oger(ShiftingLaw):
    name = "oger"
    grad_c_weights = (0.0, 1.0)

    def __init__(self, scene):
        super().__init__(scene)
        self.u_char = scene.physics.reference_velocity

    def velocity(self, system, scheme, dt, grad=None):
        """du = -U_char 2 dx grad C (thesis eq. 6.32), |du| <= 0.25 |u_i|. Local."""
        p = system.particles
        grad = _grad_c_hat(self, system, scheme, grad)
        raw = -self.u_char * 2.0 * self.dx * grad
        limit = 0.25 * np.sqrt((p.owned("velocity") ** 2).sum(axis=1))
        out = p.owned("shift_velocity")
        limit_magnitude(raw, limit, out)
        out *= fluid_mask(system)[:, None]

    def describe(self):
        return "shifting: Oger du = -Ma c0 2 dx grad C, |du| <= 0.25 |u| (thesis eq. 6.32)"


class Neuhauser(ShiftingLaw):
    name = "neuhauser"
    fields = (SHIFT_VELOCITY, FieldSpec("transport_velocity", ("d",)))

    def __init__(self, scene):
        super().__init__(scene)
        spec, physics = scene.shifting, scene.physics
        self.ps = spec.neuhauser_ps
        self.fictitious = spec.fictitious_pressure
        self.alpha = 0.1
        self.c0 = physics.sound_speed
        self.rho0 = physics.density
        self.p_ref = physics.density * physics.sound_speed ** 2 / TAIT_GAMMA

    def velocity(self, system, scheme, dt, grad=None):
        """Neuhauser's shifting velocity (thesis eq. 6.33-6.35 with P_S, eq. 7.1, or P^F, eq. 7.4). Collective."""
        p = system.particles
        if self.fictitious:  # P^F / rho0 = p_ref / rho0 (V0 / V)^gamma (eq. 7.3)
            pref = self.p_ref / self.rho0 * (scheme.initial_volume(system) / p["volume"]) ** TAIT_GAMMA
        else:
            pref = np.full(p.n_local, self.ps * self.p_ref / self.rho0)
        system.refresh(["transport_velocity"])
        acc = np.zeros((p.n_owned, p.dim))
        neuhauser_acceleration(p["position"], p["volume"], p["transport_velocity"], pref, system.nbr_ptr,
                               system.nbr_idx, system.kernel.params, self.c0, self.alpha, acc)
        p.owned("shift_velocity")[:] = dt * acc * fluid_mask(system)[:, None]

    def end_step(self, system, scheme, dt):
        p = system.particles
        p.owned("transport_velocity")[:] = p.owned("velocity") + p.owned("shift_velocity")

    def describe(self):
        how = "fictitious pressure P^F (eq. 7.4)" if self.fictitious else f"P_S = {self.ps:g} (eq. 7.1)"
        return f"shifting: Neuhauser Riemann-based transport-velocity correction with {how}, alpha = 0.1"


def make_velocity_shift(scene) -> VelocityShift:
    laws = {"delta_plus": DeltaPlus, "lind": Lind, "skillen": Skillen, "oger": Oger, "neuhauser": Neuhauser}
    return laws.get(scene.shifting.method, NoVelocityShift)(scene)
