"""Clone particles (seed 004 section III): the local mirroring of normals (eq. 5, sign corrected), of the
divergence velocity (eq. 6), of the Laplacian velocity (eq. 7) and of the pressure (eq. 8-9, with the full
body-force term), checked on the particles of a real scene next to a wall and at a corner."""

import numpy as np
import pytest
from mpi4py import MPI

from psph.drivers.fluid import FluidDriver
from psph.particles import Kind
from psph.scene.load import load_scene
from tests.helpers import CASES

DX = 0.05


def cavity(tmp_path, **sets):
    scene = load_scene(CASES / "lid_driven_cavity.toml", [f"domain.dx={DX}", *[f"{k}={v}" for k, v in sets.items()]])
    driver = FluidDriver(scene, MPI.COMM_SELF, tmp_path)
    system = driver.system
    p = system.particles
    for name in ("velocity", "pressure"):
        p[name][:] = 0.0
    p["density"][:] = scene.physics.density
    driver.scheme.walls.place(system, 0.0)
    p["velocity"][p["kind"] != Kind.FLUID] = 0.0
    return driver, system, p


def wall_rates(driver, system, row, velocity=(0.0, 0.0), pressure=0.0):
    """(d rho, d momentum) the walls alone give fluid particle `row` moving at `velocity`."""
    p = system.particles
    p["velocity"][row] = velocity
    p["pressure"][row] = pressure
    d_rho, d_mom = np.zeros(p.n_local), np.zeros((p.n_local, 2))
    walls = driver.scheme.walls
    lid = walls.bodies[0].lid.copy()
    walls.add(system, driver.scheme, 0.0, d_rho, d_mom)
    assert np.array_equal(lid, walls.bodies[0].lid)
    return d_rho[row], d_mom[row]


def particle_at(p, x, y):
    pos = p.owned("position")
    fluid = p.owned("kind") == Kind.FLUID
    d = np.where(fluid, np.hypot(pos[:, 0] - x, pos[:, 1] - y), np.inf)
    return int(np.argmin(d))


def test_approach_to_a_wall_compresses_and_pressure_repels(tmp_path):
    """Moving towards the bottom wall mirrors the normal velocity (eq. 6): the particle is compressed;
    moving along it is not; a positive pressure is pushed back by the clones (eq. 8)."""
    driver, system, p = cavity(tmp_path, **{"physics.reynolds": 1e12})
    i = particle_at(p, 0.5 + DX / 2, DX / 2)
    towards, _ = wall_rates(driver, system, i, velocity=(0.0, -1.0))
    along, _ = wall_rates(driver, system, i, velocity=(1.0, 0.0))
    assert towards > 0 and abs(along) < 1e-12 * towards
    _, push = wall_rates(driver, system, i, pressure=1.0)
    assert push[1] > 0 and abs(push[0]) < 1e-10 * push[1]


def test_corner_second_wall_still_mirrors_the_approach(tmp_path):
    """Eq. 5 as printed (n_j . (r_j - r_i) > 0) holds for every ordinary wall particle, so every clone
    would take the closest node's normal: near a corner, approaching the other wall would not compress.
    With the corrected sign, a particle half a spacing from the left wall and 2.5 from the bottom is
    compressed when it moves down, about as much as at the same distance from a plain bottom wall."""
    driver, system, p = cavity(tmp_path, **{"physics.reynolds": 1e12})
    corner = particle_at(p, DX / 2, 2.5 * DX)
    plain = particle_at(p, 0.5 + DX / 2, 2.5 * DX)
    down_corner, _ = wall_rates(driver, system, corner, velocity=(0.0, -1.0))
    down_plain, _ = wall_rates(driver, system, plain, velocity=(0.0, -1.0))
    assert down_plain > 0 and down_corner > 0.5 * down_plain


@pytest.mark.parametrize("side,velocity", [("bottom", 0.0), ("lid", 1.0)])
def test_laplacian_mirror_is_the_linear_extension_of_a_shear(tmp_path, side, velocity):
    """Eq. 7: for u = u_b + gamma s (s: distance from the wall), the clones carry u_b - gamma s_j, the
    linear continuation, so the wall's viscous force equals the one of a fluid continued beyond the wall
    with that profile: for each fluid particle near the wall, fluid + clone viscous sums equal the sum over
    the full lattice of the continued profile."""
    driver, system, p = cavity(tmp_path, **{"physics.reynolds": 1.0})
    pos = p["position"]
    gamma = 0.7
    dist = pos[:, 1] if side == "bottom" else 1.0 - pos[:, 1]
    profile = velocity - gamma * dist if side == "lid" else gamma * dist
    fluid = p["kind"] == Kind.FLUID
    p["velocity"][:, 0] = np.where(fluid, profile, p["velocity"][:, 0])
    from psph.compute.sums import viscous_pi

    i = particle_at(p, 0.5 + DX / 2, DX / 2 if side == "bottom" else 1.0 - DX / 2)
    d_rho, d_mom = np.zeros(p.n_local), np.zeros((p.n_local, 2))
    driver.scheme.walls.add(system, driver.scheme, 0.0, d_rho, d_mom)
    mu = driver.scheme.mu
    fluid_only = np.zeros((p.n_local, 2))
    u_fluid = np.where(fluid[:, None], p["velocity"], 0.0)
    vol_fluid = np.where(fluid, p["volume"], 0.0)
    viscous_pi(pos, vol_fluid, system.nbr_ptr, system.nbr_idx, system.kernel.params, u_fluid, fluid_only)
    continued = np.zeros((p.n_local, 2))
    u_all = np.stack([profile, np.zeros(p.n_local)], 1)
    viscous_pi(pos, p["volume"], system.nbr_ptr, system.nbr_idx, system.kernel.params, u_all, continued)
    wall_part = d_mom[i] / p["volume"][i] / mu
    assert np.allclose(fluid_only[i] + wall_part, continued[i], atol=1e-9 * gamma / DX)


@pytest.mark.parametrize("where", ["wall", "corner"])
def test_negative_pressure_is_not_pulled_into_the_wall(tmp_path, where):
    """Tensile switch (seed 004 eq. 3): where p_i < 0 the pressure force is -sum_j (p_j - p_i) grad_i W_ij V_j
    over every neighbour, the clones included. Applied to the fluid pairs only, a particle in uniform
    suction (p_j = p_i < 0 on both sides) kept 2 |p_i| |sum_clones grad_i W_ij V_j| of attraction to the
    wall: the moving square's wake particles were pulled through its rear corner (t = 0.94 at D/dx = 10).
    With the switch on the clones too, uniform suction exerts no force on the particle; without the switch
    the plus form pulls it to the wall; the force on the body stays the plus form's (suction drags it)."""
    driver, system, p = cavity(tmp_path, **{"physics.reynolds": 1e12})
    i = particle_at(p, 0.5 + DX / 2 if where == "wall" else DX / 2, DX / 2)
    _, push = wall_rates(driver, system, i, pressure=1.0)
    body_push = driver.scheme.walls.force[0, 0].copy()
    _, pull = wall_rates(driver, system, i, pressure=-1.0)
    body_pull = driver.scheme.walls.force[0, 0].copy()
    assert push[1] > 0 and np.abs(pull).max() < 1e-12 * push[1]
    assert body_push[1] < 0 and np.allclose(body_pull, -body_push, rtol=1e-12)
    driver.scheme.tensile = False
    _, plus = wall_rates(driver, system, i, pressure=-1.0)
    assert np.allclose(plus, -push, rtol=1e-12)
