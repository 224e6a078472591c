"""delta-ALE-SPH: conservation identities of the right-hand side, equation of state, short runs."""

import numpy as np
import pytest
from mpi4py import MPI

from psph.schemes.delta_ale import DeltaALE
from psph.schemes.eos import LinearEOS, TaitEOS
from psph.simulation import build_system
from tests.conftest import periodic_scene


def fluid(scheme="delta_ale", shifting="delta_plus", n=16, sigma=0.2, **physics):
    scene = periodic_scene(n=n, sigma=sigma, initial={"velocity": "taylor_green"},
                           physics={"scheme": scheme, **physics}, time={"t_end": 1.0},
                           shifting={"method": shifting})
    s = DeltaALE(scene)
    system = build_system(scene, MPI.COMM_SELF, specs=s.field_specs(), halo_fields=s.halo_fields())
    s.initialize(system)
    return scene, s, system


@pytest.mark.parametrize("shifting", ["none", "delta_plus", "neuhauser", "lind", "oger", "skillen"])
def test_mass_and_momentum_rates_sum_to_zero(shifting):
    """Seed 001 section 4.1: the mass and momentum right-hand sides are antisymmetric pair sums (the
    tensile switch, which breaks momentum conservation by design, is off here)."""
    _, scheme, system = fluid(shifting=shifting, tensile_switch=False)
    p = system.particles
    p.owned("density")[:] *= 1.0 + 0.01 * np.sin(np.arange(p.n_owned))  # uneven masses and densities
    scheme.set_state(system, scheme.state(system))
    rates = scheme.rhs(system, 0.0, 1e-3)
    assert abs(rates["mass"].sum()) < 1e-13 * np.abs(rates["mass"]).sum() + 1e-300
    mom = rates["momentum"].sum(axis=0)
    assert np.abs(mom).max() < 1e-12 * np.abs(rates["momentum"]).sum()


@pytest.mark.parametrize("scheme", ["delta_ale", "delta_ale_const_volume"])
def test_standard_sph_computes_no_density_gradient_and_gets_the_same_rates(scheme):
    """delta = delta_m = 0: the diffusive terms cost nothing (no density gradient, no pair terms), and the
    rates are those of the same scheme with them computed at zero coefficients, bit for bit."""
    _, s, system = fluid(scheme, "delta_plus", delta=0.0, **({"delta_m": 0.0} if scheme == "delta_ale" else {}))
    p = system.particles
    p.owned("density")[:] *= 1.0 + 0.01 * np.sin(np.arange(p.n_owned))
    s.set_state(system, s.state(system))
    p["grad_rho"][:] = 0.0
    lean = s.rhs(system, 0.0, 1e-3)
    assert not s.reads_grad_rho and not np.any(p["grad_rho"])
    s.diffusive = s.reads_grad_rho = True
    full = s.rhs(system, 0.0, 1e-3)
    assert np.abs(p["grad_rho"]).max() > 1e-3
    for key in full:
        assert np.array_equal(lean[key], full[key]), key


def test_constant_mass_variant_conserves_momentum_without_shifting():
    _, scheme, system = fluid("delta_ale_const_mass", "none", tensile_switch=False)
    rates = scheme.rhs(system, 0.0, 1e-3)
    force = system.particles.owned("mass")[:, None] * rates["velocity"]
    assert np.abs(force.sum(axis=0)).max() < 1e-12 * np.abs(force).sum()


def test_tensile_switch_breaks_momentum_conservation_only_where_pressure_is_negative():
    _, scheme, system = fluid(shifting="none")
    p = system.particles
    rates = scheme.rhs(system, 0.0, 1e-3)
    assert np.abs(rates["momentum"].sum(axis=0)).max() > 1e-6  # TGV has p < 0 regions: not conserved
    p.owned("density")[:] += 0.02  # all pressures positive: the switch never acts
    scheme.set_state(system, scheme.state(system))
    rates = scheme.rhs(system, 0.0, 1e-3)
    assert np.abs(rates["momentum"].sum(axis=0)).max() < 1e-12 * np.abs(rates["momentum"]).sum()


def test_fluid_at_rest_stays_at_rest():
    scene = periodic_scene(n=12, physics={"scheme": "delta_ale"}, time={"t_end": 1.0})
    s = DeltaALE(scene)
    system = build_system(scene, MPI.COMM_SELF, specs=s.field_specs(), halo_fields=s.halo_fields())
    s.initialize(system)
    rates = s.rhs(system, 0.0, 1e-3)
    for k in ("density", "mass", "momentum"):
        assert np.abs(rates[k]).max() < 1e-12


@pytest.mark.parametrize("shifting", [{"method": "neuhauser"}, {"method": "neuhauser", "fictitious_pressure": True},
                                      {"method": "delta_plus"}, {"method": "lind"}])
def test_shifting_velocity_vanishes_on_a_lattice(shifting):
    """A lattice at rest has grad C = 0 and a uniform velocity: no law may shift it. The fictitious pressure
    (thesis eq. 7.3) reads V0 / V of the neighbours, halo copies (periodic images) included: V0 was not
    carried in the halo, so its zero gave the particles next to the periodic boundaries a spurious push."""
    scene = periodic_scene(n=12, physics={"scheme": "delta_ale"}, time={"t_end": 1.0}, shifting=shifting)
    s = DeltaALE(scene)
    system = build_system(scene, MPI.COMM_SELF, specs=s.field_specs(), halo_fields=s.halo_fields())
    s.initialize(system)
    s.rhs(system, 0.0, 1e-3)
    assert np.abs(system.particles.owned("shift_velocity")).max() < 1e-12


def test_equations_of_state_invert():
    rho = np.array([0.95, 1.0, 1.03])
    for eos in (LinearEOS(10.0, 1.0), TaitEOS(10.0, 1.0)):
        assert np.allclose(eos.density(eos.pressure(rho)), rho)
        assert eos.pressure(np.array([1.0]))[0] == 0.0
    tait = TaitEOS(10.0, 1.0)  # p = c0^2 rho0 / 7 ((rho/rho0)^7 - 1): slope c0^2 at rho0
    assert (tait.pressure(np.array([1.0 + 1e-7])) / 1e-7)[0] == pytest.approx(100.0, rel=1e-5)


def test_tensile_switch_is_off_in_the_free_surface_region(tmp_path):
    """Seed 004 eq. 3: at a uniform negative pressure the switch (p_j - p_i) cancels the pressure force
    everywhere it acts; in the free-surface region (surface particles and their neighbours) the plus form
    stays, which pushes the surface in as the free-surface condition requires."""
    from psph.drivers.fluid import FluidDriver
    from psph.particles import Kind
    from psph.scene.load import load_scene
    from tests.helpers import CASES

    scene = load_scene(CASES / "elliptical_drop.toml", ["domain.dx=0.1", "packing.iterations=0",
                                                          "physics.tensile_switch=true", "initial.sigma_over_dx=0.1"])
    driver = FluidDriver(scene, MPI.COMM_SELF, tmp_path)
    scheme, system = driver.scheme, driver.system
    assert scheme.step_surface is not None and not scheme.shift.active  # detected for the switch alone
    p = system.particles
    p.owned("pressure")[:] = -0.1
    p.owned("velocity")[:] = 0.0
    scheme.detect_surface(system)
    region = p.owned("free_surface") != 0
    fluid = p.owned("kind") == Kind.FLUID
    assert 0 < np.count_nonzero(region) < np.count_nonzero(fluid)

    def acceleration(tensile, step_surface):
        scheme.tensile, scheme.step_surface = tensile, step_surface
        rates = scheme.rhs(system, 0.0, 1e-3)
        return np.asarray(rates["momentum" if "momentum" in rates else "velocity"]).copy()

    surface = scheme.step_surface
    seed004, plus, everywhere = acceleration(True, surface), acceleration(False, None), acceleration(True, None)
    interior = fluid & ~region
    assert np.array_equal(seed004[region], plus[region])
    assert np.array_equal(seed004[interior], everywhere[interior])
    assert np.abs(everywhere[region] - plus[region]).max() > 0.1 * np.abs(plus[region]).max() > 0.0


def test_diffusion_switch_follows_the_detected_lambda(tmp_path):
    """free_surface.lambda_diffusion (seed 001 section 6.3) reaches the kernel: with every lambda below the
    threshold the rates equal those with delta = delta_m = 0; at the detected lambda of a dam break's column
    the surface rows lose part of their diffusion and the deep ones keep all of it."""
    from psph.drivers.fluid import FluidDriver
    from psph.particles import Kind
    from psph.scene.load import load_scene
    from tests.helpers import CASES

    # no shifting: its restriction near the surface reads lambda too
    scene = load_scene(CASES / "dam_break.toml", ["domain.dx=0.1", "initial.sigma_over_dx=0.2", "shifting.method=none"])
    driver = FluidDriver(scene, MPI.COMM_SELF, tmp_path)
    scheme, system = driver.scheme, driver.system
    p = system.particles
    rng = np.random.default_rng(3)
    p.owned("density")[:] *= 1.0 + 0.01 * rng.standard_normal(p.n_owned)  # something to diffuse
    p.owned("mass")[:] *= 1.0 + 0.01 * rng.standard_normal(p.n_owned)
    scheme.detect_surface(system)
    lam = p["surface_lambda"].copy()

    def rates(threshold=0.6, delta=0.1, lam_value=None):
        scheme.lambda_diffusion, scheme.delta, scheme.delta_m = threshold, delta, delta
        p["surface_lambda"][:] = lam if lam_value is None else lam_value
        r = scheme.rhs(system, 0.0, 1e-3)
        return np.concatenate([np.asarray(r[k]).reshape(p.n_owned, -1) for k in sorted(r)], axis=1)

    fluid = p.owned("kind") == Kind.FLUID
    assert np.array_equal(rates(lam_value=0.1)[fluid], rates(delta=0.0)[fluid])
    switched, everywhere = rates(threshold=0.6), rates(threshold=0.0)  # (the column has no lambda below 0.2)
    low = fluid & (lam[:p.n_owned] <= 0.6)
    deep = fluid & (p.owned("position")[:, 1] < 0.5) & (p.owned("position")[:, 0] < 1.5)
    assert low.any() and np.abs(switched[low] - everywhere[low]).max() > 0.0
    assert np.array_equal(switched[deep], everywhere[deep])
