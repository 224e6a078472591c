"""Initial conditions: lattice numbering, per-gid perturbation statistics, analytic fields."""

import numpy as np
from mpi4py import MPI

from psph.analytic import taylor_green
from psph.compute.random import gaussian_by_gid
from psph.initial import create_particles, lattice_block
from tests.conftest import periodic_scene


def test_lattice_blocks_cover_every_gid_once():
    scene = periodic_scene(dim=3, n=7)
    parts = [lattice_block(scene.domain, r, 3) for r in range(3)]
    gid = np.concatenate([g for g, _ in parts])
    pos = np.concatenate([p for _, p in parts])
    assert np.array_equal(gid, np.arange(343))
    assert np.allclose(pos.min(axis=0), 0.5 / 7) and np.allclose(pos.max(axis=0), 1 - 0.5 / 7)
    assert len(np.unique(np.round(pos * 14).astype(int), axis=0)) == 343


def test_perturbation_depends_only_on_seed_and_gid():
    gid = np.arange(200000, dtype=np.int64)
    z = gaussian_by_gid(42, gid, 3)
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1.0) < 0.01
    assert abs(np.corrcoef(z[:, 0], z[:, 1])[0, 1]) < 0.01
    assert abs(np.mean(z[:, 0] ** 4) - 3.0) < 0.05  # Gaussian kurtosis
    shuffled = np.random.default_rng(0).permutation(gid)
    assert np.array_equal(gaussian_by_gid(42, shuffled, 3), z[shuffled])
    assert not np.allclose(gaussian_by_gid(43, gid[:10], 3), z[:10])


def test_taylor_green_initial_fields():
    scene = periodic_scene(dim=2, n=16, sigma=0.1, initial={"velocity": "taylor_green"},
                           physics={"reference_velocity": 2.0, "density": 3.0})
    p = create_particles(scene, MPI.COMM_SELF)
    vel, pres = taylor_green(p.owned("position"), U=2.0, rho=3.0)
    assert np.allclose(p.owned("velocity"), vel) and np.allclose(p.owned("pressure"), pres)
    assert "velocity" not in create_particles(periodic_scene(dim=2, n=16), MPI.COMM_SELF)


def test_a_uniform_stream_is_carried_unchanged(tmp_path):
    """initial.velocity = "uniform": a bi-periodic box of fluid moving at U0 is an exact steady solution of
    every term of delta-ALE-SPH (all differences u_j - u_i, p_j - p_i and the shifting velocity vanish on
    the lattice): after 26 steps with delta+ shifting the velocity is still U0 and the density rho0 to
    round-off, and each particle has moved by U0 t (a check of Galilean invariance at rest in the frame)."""
    import h5py

    from tests.helpers import CASES, run_psph

    u0 = np.array([0.3, -0.2])
    out = tmp_path / "stream"
    res = run_psph("run", CASES / "taylor_green.toml", "--out", out, "--quiet", "--set", "initial.velocity=uniform",
                   "--set", "initial.uniform_velocity=[0.3, -0.2]", "--set", "domain.dx=0.1", "--set",
                   "time.t_end=0.1", "--set", "shifting.method=delta_plus", "--set", "iips.update=none")
    assert res.returncode == 0, res.stderr
    with h5py.File(out / "snapshot_000000.h5") as start, h5py.File(sorted(out.glob("snapshot_*.h5"))[-1]) as end:
        order0, order1 = np.argsort(start["particles/gid"][()]), np.argsort(end["particles/gid"][()])
        x0, x1 = start["particles/position"][()][order0], end["particles/position"][()][order1]
        vel, rho, t = end["particles/velocity"][()], end["particles/density"][()], end.attrs["time"]
    assert t == 0.1 and np.abs(vel - u0).max() < 1e-12 and np.abs(rho - 1.0).max() < 1e-12
    moved = (x1 - x0 - u0 * t + 0.5) % 1.0 - 0.5  # (periodic)
    assert np.abs(moved).max() < 1e-12


def test_a_uniform_velocity_needs_one_entry_per_axis():
    import pytest

    from psph.errors import SceneError

    with pytest.raises(SceneError, match=r"initial.uniform_velocity: initial.velocity = \"uniform\" needs 2 entries"):
        periodic_scene(dim=2, n=16, initial={"velocity": "uniform", "uniform_velocity": [1.0]})


def test_a_uniform_velocity_not_below_the_speed_of_sound_is_refused():
    """As an inflow's and a body's are: 1e160 ran to a time step of 0 at step 1."""
    import pytest

    from psph.errors import SceneError

    for speed in (10.0, 1e160):  # (c0 = 10)
        with pytest.raises(SceneError, match=r"initial.uniform_velocity: the fluid would start at .*, not below the "
                                             r"speed of sound physics.sound_speed = 10"):
            periodic_scene(dim=2, n=16, initial={"velocity": "uniform", "uniform_velocity": [speed, 0.0]},
                           physics={"scheme": "delta_ale", "sound_speed": 10.0}, time={"t_end": 0.1})
    periodic_scene(dim=2, n=16, initial={"velocity": "uniform", "uniform_velocity": [9.9, 0.0]},
                   physics={"scheme": "delta_ale", "sound_speed": 10.0}, time={"t_end": 0.1})
