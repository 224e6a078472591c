"""What happens to the fluid fields when IIPS moves particles after a physical step (thesis 000 ch. 9).

    none   positions change, fields do not (the thesis' "implicit iterative shifting")
    nfts   fictitious time step (eq. 9.7): the displacements are swept in N = ceil(max|dx| / (CFL dx))
           sub-steps (eq. 9.6, CFL = time.cfl; the run's total is summary.json's nfts_substeps) whose ALE
           fluxes update volume, mass and momentum (delta_ale only: the variants fix
           masses or volumes); IIPS then levels the concentration of the reference volumes V0
    mls1   first-order MLS re-interpolation (eq. 9.8) of volume, density and velocity from the pre-shift
           positions; mass = rho V (delta_ale), or V = m / rho (constant mass), or m = V0 rho. Where a moment
           matrix is singular the fit falls back to a lower order (Shepard last); the run's count of such
           fits is summary.json's mls_fallbacks
    mls2   second-order MLS re-interpolation (eq. 9.9), same fields
           (mls1, mls2: of every fluid particle, as thesis section 9.1.2 does; with iips.mls_fit = "moved",
           of the particles IIPS moved only, the ones it held in a free-surface region keeping theirs)
    mls1_increment, mls2_increment
           the MLS fit's increment only: f_i += MLS[f](x_i') - MLS[f](x_i), the Taylor-series correction of
           eq. 6.10 (Xu et al. 2009) with the MLS polynomial as the expansion. A particle that did not move
           keeps its values exactly, so a call does not smooth; a quadratic (mls2) field is still remapped
           exactly. Next to walls the particle keeps what the walls gave it, where the plain remap, which
           sees only fluid particles (solid particles weigh nothing in the fit), extrapolates (README: the
           lid-driven cavity).
Kernels in psph.compute.field_update.
"""

import math

import numpy as np

from psph.compute.field_update import mls_interpolate, nfts_increments
from psph.compute.neighbours import build_cross_lists
from psph.errors import NumericalError
from psph.parallel.comm import allreduce_sum, raise_if_any
from psph.parallel.halo import build_halo_pattern, halo_copies
from psph.particles import FieldSpec, Kind
from psph.shifting.iips import SHIFT_FIELD, largest_shift


class NoFieldUpdate:
    name = "none"
    # the run's counters this update adds to (history and summary); after() returns their increments
    counters = ()
    # the volumes weighting the concentration C = sum_j W_ij V_j that IIPS levels (ImplicitShifting.volume)
    concentration_volume = "volume"

    def specs(self, dim):
        return ()

    def before(self, system, scheme):
        """Called before each IIPS call: register this update's fields."""
        for spec in self.specs(system.particles.dim):
            system.particles.add_field(spec)

    def after(self, system, scheme) -> dict:
        return {}

    # what an update changes: after it, their halo copies are refreshed, so that what reads them before the
    # next step refreshes its fields (the history's grad C, a snapshot's halo-based diagnostics) sees the
    # owners' values, on every rank count
    CHANGED = ("volume", "density", "mass", "velocity", "pressure")

    @classmethod
    def refresh(cls, system) -> None:
        """Refresh the halo copies of the fields an update changed. Collective."""
        system.refresh(cls.CHANGED)


class FictitiousTimeStep(NoFieldUpdate):
    """NFTS (thesis eq. 9.7). Its volume line gives a particle the room its neighbours vacate, V_i += V_i
    <div dx>_i, so the volumes follow the displacements. IIPS therefore levels the concentration of the
    constant reference volumes V0 (concentration_volume), not of these volumes: IIPS linearises C with the
    omega_j fixed (thesis eq. 8.7), and were the omega_j the NFTS volumes, a particle whose volume exceeds
    the room it has (a suction peak, a wall corner) would make IIPS push its neighbours away by the excess,
    NFTS would add that room to its volume and mass, the excess would survive and every later IIPS call
    would grow the particle again (the moving square at D/dx = 10 stopped at t = 1.07 with V = 1.5 V0 and
    m = 1.5 m0 above the square's front corner; tests/shifting/test_field_update.py). With V0 the
    displacements do not depend on the volumes and NFTS moves each volume by the ALE flux of a purely
    geometric correction, as seed 001 section 5 evaluates its shifting law with V0."""

    name = "nfts"
    concentration_volume = "volume0"
    counters = ("nfts_substeps",)

    def specs(self, dim):
        return (FieldSpec("nfts_step", ("d",)),)

    def __init__(self, cfl, dx):
        """cfl: the run's time.cfl, which bounds each sub-step's largest displacement to cfl dx (eq. 9.6)."""
        self.cfl, self.dx = cfl, dx

    def after(self, system, scheme) -> dict:
        """Sweep the call's displacements in N = ceil(max|dx| / (cfl dx)) sub-steps (thesis eq. 9.6-9.7);
        returns {"nfts_substeps": N}. Collective."""
        p = system.particles
        shift = p.owned(SHIFT_FIELD.name)
        largest = largest_shift(system)
        if largest == 0.0:
            return {"nfts_substeps": 0}
        n = max(1, math.ceil(largest / (self.cfl * self.dx)))
        p.owned("position")[:] -= shift  # back to the pre-shift positions, then sweep in n steps
        p.owned("nfts_step")[:] = shift / n
        p.owned(SHIFT_FIELD.name)[:] = 0.0
        system.update()
        walls = "normal" in p.names
        for sub in range(n):
            system.refresh(["position", "volume", "density", "velocity", "nfts_step"])
            # normals of the solid neighbours (clones, see nfts_increments; none: no walls), read after each
            # sub-step's update: a rebuild there replaces every field array and reorders the rows (a parallel
            # audit: the sweep's later sub-steps read the normals of other particles, rank-dependently)
            normal = p["normal"] if walls else np.zeros((1, p.dim))
            vol, rho, vel = p.owned("volume"), p.owned("density"), p.owned("velocity")
            d_vol, d_mass = np.zeros(p.n_owned), np.zeros(p.n_owned)
            d_mom = np.zeros((p.n_owned, p.dim))
            nfts_increments(p["position"], p["volume"], p["density"], p["velocity"], p["nfts_step"], p["kind"],
                            normal, system.nbr_ptr, system.nbr_idx, system.kernel.params, d_vol, d_mass, d_mom)
            mass = vol * rho + d_mass
            mom = (vol * rho)[:, None] * vel + d_mom
            self._check_positive(system, vol + d_vol, mass, sub, n)
            vol += d_vol
            rho[:] = mass / vol
            vel[:] = mom / mass[:, None]
            p.owned("mass")[:] = mass
            p.owned("pressure")[:] = scheme.eos.pressure(rho)
            p.owned("position")[:] += p.owned("nfts_step")
            system.update()
        self.refresh(system)
        return {"nfts_substeps": n}

    def _check_positive(self, system, vol, mass, sub, n) -> None:
        """Stop, naming NFTS, where a sub-step left a volume or mass at or below zero: a sub-step of 1 dx that
        converges on a particle takes its volume to -0.4 V (a field-update audit; the run's density check
        then named no cause). Collective."""
        p = system.particles
        # (a NaN is not this: the run's check names it as a non-finite field, a review)
        bad = np.flatnonzero((p.owned("kind") == Kind.FLUID) & ((vol <= 0.0) | (mass <= 0.0)))
        error = None
        if len(bad):
            k = bad[0]
            error = NumericalError(
                f"NFTS sub-step {sub + 1} of {n} left {len(bad)} particle(s) with a volume or mass at or below zero "
                f"(V = {vol[k]:.3g}, m = {mass[k]:.3g}): its displacements, up to time.cfl dx = "
                f"{self.cfl * self.dx:.3g} a sub-step (thesis eq. 9.6), converge faster than the volumes allow; "
                "lower time.cfl", **system.where, gid=int(p.owned("gid")[k]), position=p.owned("position")[k])
        raise_if_any(system.comm, error)


SOLID_KINDS = (Kind.WALL, Kind.BODY)


class MovingLeastSquares(NoFieldUpdate):
    counters = ("mls_fallbacks",)

    def __init__(self, order, increment=False, moved_only=False):
        self.order = order
        self.increment = increment
        self.moved_only = moved_only  # iips.mls_fit = "moved" (an increment leaves unmoved rows alone anyway)
        self.name = f"mls{order}" + ("_increment" if increment else "")

    def specs(self, dim):
        return (FieldSpec("old_position", ("d",)), FieldSpec("old_fields", (3 + dim,)))

    def before(self, system, scheme):
        super().before(system, scheme)
        p = system.particles
        p.owned("old_position")[:] = p.owned("position")
        old = p.owned("old_fields")
        old[:, 0] = p.owned("volume")
        old[:, 1] = p.owned("volume")
        old[:, 2] = p.owned("density")
        old[:, 3:] = p.owned("velocity")
        # the fit's data are the fluid's (inflow and outflow particles' included): a solid particle's stored
        # density and velocity (rho0, zero) are not the flow's there (its clone's are, per pair), and weighed
        # in they bent every fit near a wall (an audit: the linear shear of the cavity came back 0.27 U wrong
        # under the moving lid with no displacement at all, the hydrostatic density 0.47 rho0 g H along the
        # tank's walls)
        old[np.isin(p.owned("kind"), SOLID_KINDS), 0] = 0.0

    def _fit(self, system, at, old_pos, old):
        """The MLS fit of the old fields (columns 1:, weighted by the volumes of column 0) at `at`, and the
        number of its points fitted below the order."""
        ptr, idx = build_cross_lists(at, old_pos, system.kernel.support)
        out = np.zeros((len(at), old.shape[1] - 1))
        fallbacks = mls_interpolate(at, old_pos, old[:, 0], np.ascontiguousarray(old[:, 1:]), ptr, idx,
                                    system.kernel.params, self.order, out)
        return out, fallbacks

    def after(self, system, scheme):
        """Re-interpolate at the new positions from the old ones. The old positions reach other ranks
        through a halo pattern built from the old positions themselves, so a large IIPS displacement does
        not lose neighbours. Collective."""
        p = system.particles
        owned_old = p.owned("old_position")
        pattern = build_halo_pattern(system.comm, owned_old, system.decomposition, system.domain,
                                     system.list_radius)
        got = halo_copies(system.comm, pattern, {"old_position": owned_old, "old_fields": p.owned("old_fields")},
                          shifted=("old_position",))
        old_pos = np.concatenate([owned_old, got["old_position"]])
        old = np.concatenate([p.owned("old_fields"), got["old_fields"]])
        # the fluid's rows only: solids and inflow particles keep their own fields (IIPS moved neither); with
        # moved_only, so do the fluid particles IIPS held (a free-surface region), where a fit is a smoothing,
        # one-sided at the surface (README, "Field update in flows": the elliptical drop's semi-axis error at
        # t = 0.5, dx = 0.05, 0.0044 with every fluid particle re-fitted, 0.00084 without the held ones; but the
        # impinging jet rings without that smoothing)
        fitted = p.owned("kind") == Kind.FLUID
        if self.moved_only:  # by the call's displacement, not the positions: a rebuild within the call wraps
            # them across periodic edges (a review: 419 of 518 held particles re-fitted so)
            fitted &= np.any(p.owned(SHIFT_FIELD.name) != 0.0, axis=1)
        new, fallbacks = self._fit(system, p.owned("position")[fitted], old_pos, old)
        if self.increment:
            at_old, more = self._fit(system, owned_old[fitted], old_pos, old)
            new += p.owned("old_fields")[fitted, 1:] - at_old
            fallbacks += more
        error = None
        bad = np.flatnonzero(~np.all(np.isfinite(new), axis=1))
        if len(bad):  # (a field-update audit: the error named no step, time or particle)
            k = np.flatnonzero(fitted)[bad[0]]
            error = NumericalError(f"MLS update: {len(bad)} particle(s) with no old neighbour to interpolate from "
                                   "(moved farther than a kernel support from every old position)", **system.where,
                                   gid=int(p.owned("gid")[k]), position=p.owned("position")[k])
        raise_if_any(system.comm, error)
        vol, rho, mass = p.owned("volume"), p.owned("density"), p.owned("mass")
        rho[fitted] = new[:, 1]
        p.owned("velocity")[fitted] = new[:, 2:]
        if scheme.variant == 0:
            vol[fitted] = new[:, 0]
            mass[fitted] = rho[fitted] * vol[fitted]
        elif scheme.variant == 1:
            vol[fitted] = mass[fitted] / rho[fitted]
        else:
            mass[fitted] = p.owned("volume0")[fitted] * rho[fitted]
        p.owned("pressure")[fitted] = scheme.eos.pressure(rho[fitted])
        self.refresh(system)
        return {"mls_fallbacks": int(allreduce_sum(system.comm, fallbacks))}


def make_field_update(scene):
    mode = scene.iips.update
    if mode == "nfts":
        return FictitiousTimeStep(scene.time.cfl, scene.domain.dx)  # (a field-update audit: it was 0.2 always)
    if mode.startswith("mls"):
        return MovingLeastSquares(int(mode[3]), increment=mode.endswith("_increment"),
                                  moved_only=scene.iips.mls_fit == "moved")
    return NoFieldUpdate()
