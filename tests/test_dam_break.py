"""The dam break (cases/dam_break.toml, seed 001 section 6.3): the pressure just after the release against
the incompressible solution (analytic.dam_break_initial), the surge behind Ritter's front with its mass kept
and its energy falling, and the same run on 1, 2 and 3 ranks."""

import numpy as np
import pytest
from mpi4py import MPI

from psph.drivers.fluid import FluidDriver
from psph.io.history import read_history
from psph.scene.load import load_scene
from psph.studies import DAM_BREAK_PROBES, release_pressure_errors
from tests.helpers import CASES

H, B = 1.0, 2.0


def test_the_release_averages_to_the_incompressible_initial_pressure(tmp_path):
    """At H/dx = 20 with c0 = 40 sqrt(g H), the pressure averaged over t sqrt(g/H) in [0, 0.2] (the sound
    the release sends through the column averages out) is within 0.025 rho0 g H (RMS over nine points inside
    the column) of the incompressible fluid's initial pressure; the hydrostatic pressure the run starts from
    is 5 times further off. run_scripts/dam_break.py measures it at more resolutions and sound speeds."""
    scene = load_scene(CASES / "dam_break.toml", ["domain.dx=0.05", "physics.sound_speed=40", "time.t_end=0.2",
                                                   "output.every=0", "output.history_every=1", DAM_BREAK_PROBES])
    with FluidDriver(scene, MPI.COMM_SELF, tmp_path) as driver:
        driver.run()
    error, start, swing = release_pressure_errors(tmp_path)
    rms, start_rms = np.sqrt(np.mean(error**2)), np.sqrt(np.mean(start**2))
    assert rms < 0.025 and start_rms > 5.0 * rms, (rms, start_rms)
    assert swing.max() > 0.1  # the sound is there: the average is what is compared


def test_the_surge_runs_behind_ritter_and_keeps_its_mass(tmp_path):
    """H/dx = 10 to t sqrt(g/H) = 1.6: the front leaves the column's face and stays behind Ritter's dry-bed
    front B + 2 sqrt(g H) t, the residual column at the back wall falls, the mass is kept to round-off, and
    the kinetic plus potential energy rises by no more than the elastic energy the compressed column held
    (the collapse releases potential energy that the artificial viscosity and the diffusive terms dissipate)."""
    scene = load_scene(CASES / "dam_break.toml", ["domain.dx=0.1", "time.t_end=1.6", "output.every=0",
                                                   "output.history_every=10"])
    with FluidDriver(scene, MPI.COMM_SELF, tmp_path) as driver:
        driver.run()
    rows = read_history(tmp_path / "history.csv")
    t = np.array([r["time"] for r in rows])
    front = np.array([r["front_x"] for r in rows])
    energy = np.array([r["kinetic_energy"] + r["potential_energy"] for r in rows])
    mass = np.array([r["total_mass"] for r in rows])
    assert front[0] == pytest.approx(B - 0.05) and rows[0]["column_height"] == pytest.approx(H - 0.05)
    assert np.all(np.diff(front) > -0.05) and front[-1] > B + 1.0
    assert np.all(front <= B + 2.0 * t)
    assert rows[-1]["column_height"] < 0.9 * H
    assert np.abs(mass / mass[0] - 1.0).max() < 1e-12
    # the hydrostatic column's elastic energy int p^2 / (2 rho0 c0^2) = rho0 g^2 B H^3 / (6 c0^2) is all the
    # flow can gain on top of the potential energy it releases
    elastic = B * H**3 / (6.0 * scene.physics.sound_speed**2)
    assert rows[-1]["kinetic_energy"] > 0.1 and np.all(energy - energy[0] <= elastic)
    assert energy[-1] < energy[0] - 0.01  # dissipated
    # sum m g y over the lattice's midpoints, m = rho dx^2 with rho = rho0 + rho0 g (H - y) / c0^2
    y = (np.arange(10) + 0.5) * 0.1
    columns = round(B / 0.1)
    expected = columns * (y * (1.0 + (H - y) / scene.physics.sound_speed**2)).sum() * 0.1**2
    assert rows[0]["potential_energy"] == pytest.approx(expected, rel=1e-12)


def test_a_flow_faster_than_the_shifting_laws_reference_velocity_is_warned_about(tmp_path):
    """A delta-ALE audit: the dam break reaches 3.2 sqrt(g H) against physics.reference_velocity = 1, the
    U_max of delta+'s strength and cap (seed 001 eq. 16-17), and nothing said so. Here U = 0.5: by t = 1 the
    front runs at over 2 U, and the log says so once, naming the key; at U = 1 it stays under 2 U, silent."""
    said = {}
    for u, t_end in ((0.5, 1.0), (1.0, 1.0)):
        scene = load_scene(CASES / "dam_break.toml", ["domain.dx=0.1", f"time.t_end={t_end}", "output.every=0",
                                                       "output.probes=[]", f"physics.reference_velocity={u}"])
        lines = said[u] = []
        with FluidDriver(scene, MPI.COMM_SELF, tmp_path / str(u), log=lines.append) as driver:
            driver.run()
    warnings = [line for line in said[0.5] if line.startswith("psph: warning: step ")]
    assert len(warnings) == 1 and ", 2 times physics.reference_velocity = 0.5, which shifting.method = " \
        "'delta_plus' takes for the flow's largest speed" in warnings[0], said[0.5]
    assert not [line for line in said[1.0] if "warning" in line]


@pytest.mark.long
def test_the_film_on_the_right_wall_is_not_shifted_through_it(tmp_path):
    """H/dx = 10 to t sqrt(g/H) = 5.5: the run-up's film on the right wall stays in the tank, no particle
    is mirrored back (history column wall_reflections), and at the history's rows none is within half a
    spacing of a solid particle (min_wall_spacing). Before WallTerms.keep_shift_off, a particle of the
    film's surface, its delta+ shifting velocity projected on the surface's tangent and so tilted into the
    wall, crossed the wall's line from step 2 731 on and was mirrored back again and again: 20 reflections
    by t = 5.5 (measured by hand with keep_shift_off replaced by a no-op; 186 from step 2 569 on with the
    solid rows of the domain's lattice, boundaries.extended_lattice)."""
    scene = load_scene(CASES / "dam_break.toml", ["domain.dx=0.1", "time.t_end=5.5", "output.every=0",
                                                   "output.history_every=100"])
    with FluidDriver(scene, MPI.COMM_SELF, tmp_path) as driver:
        driver.run()
    rows = read_history(tmp_path / "history.csv")
    assert rows[-1]["wall_reflections"] == 0
    # the fluid's nearest approach to a solid particle: dx on the lattice at t = 0 (the first rows dx/2 either
    # side of the walls), 0.67 dx at the closest by t = 5.5 (measured); a crossing particle would come to 0
    spacing = [r["min_wall_spacing"] for r in rows]
    assert spacing[0] == pytest.approx(1.0) and 0.5 < min(spacing) < 0.95


@pytest.mark.mpi
def test_a_crossing_is_mirrored_back_on_every_rank_count_with_ranks_holding_no_fluid(comm, mpi_tmp_path):
    """The crossing's log gathers each rank's deepest: a rank owning no fluid (the dam break's last rank on 3)
    took an argmax of nothing and left the others waiting (a review). The first fluid particle of the lowest
    rank holding fluid, put 0.3 dx past the floor, is mirrored back and logged on any number of ranks."""
    from psph.particles import Kind

    scene = load_scene(CASES / "dam_break.toml", ["domain.dx=0.1", "output.every=0"])
    logs = []
    with FluidDriver(scene, comm, mpi_tmp_path / "run", log=logs.append) as driver:
        p = driver.system.particles
        fluid = np.flatnonzero(p.owned("kind") == Kind.FLUID)
        first = comm.allreduce(comm.rank if len(fluid) else comm.size, op=MPI.MIN)
        if comm.size == 3:
            assert comm.allreduce(int(len(fluid) == 0)) > 0  # (the case the review found)
        if comm.rank == first:
            p.owned("position")[fluid[0], 1] = -0.03
        totals = {"wall_reflections": 0}
        driver._reflect(step=1, t=0.0, totals=totals)
        assert totals["wall_reflections"] == 1
        if comm.rank == first:
            assert p.owned("position")[fluid[0], 1] == pytest.approx(0.03)
        if comm.rank == 0:
            assert "the deepest 0.3 dx past the wall of body 'tank'" in logs[-1]


@pytest.mark.mpi
def test_dam_break_matches_serial(comm, mpi_tmp_path):
    """The free surface's lambda (the diffusion switch reads it on the halo), the front and the probes on
    2 and 3 ranks as on one."""
    scene = load_scene(CASES / "dam_break.toml", ["domain.dx=0.1", "time.t_end=0.3", "output.every=0",
                                                   "output.history_every=20", "output.probes=[[1.9, 0.1]]"])
    results = {}
    for name, c in (("par", comm), ("ser", MPI.COMM_SELF)):
        out = mpi_tmp_path / f"{name}{comm.rank if name == 'ser' else ''}"
        with FluidDriver(scene, c, out) as driver:
            driver.run()
        c.Barrier()
        history = read_history(out / "history.csv")
        results[name] = [np.array([[r[k] for k in ("front_x", "column_height", "kinetic_energy",
                                                    "potential_energy", "max_density_variation")]
                                   for r in history]),
                         np.array([list(r.values()) for r in read_history(out / "probes.csv")])]
    for par, ser in zip(results["par"], results["ser"]):
        assert par.shape == ser.shape and np.allclose(par, ser, rtol=1e-8, atol=1e-12)


def test_particles_past_a_box_side_are_mirrored_back():
    """WallTerms.reflect: a fluid particle beyond a side of a fixed box container comes back by as much,
    its normal velocity reversed, and how far it had gone and past which body are returned; inside, nothing
    changes; a side along a periodic axis is no wall."""
    from psph.boundaries.clone import WallTerms

    walls = WallTerms(load_scene(CASES / "dam_break.toml"))
    pos = np.array([[5.377, 1.5], [-0.01, 0.3], [2.0, -0.02], [2.0, 3.005], [5.0, 0.5]])
    vel = np.array([[0.4, -1.0], [-0.2, 0.1], [0.3, -0.5], [0.0, 0.7], [1.0, 1.0]])
    depth, body = walls.reflect(pos, vel)
    assert np.allclose(depth, [0.01, 0.01, 0.02, 0.005, 0.0], atol=1e-12)
    assert list(body) == ["tank"] * 4 + [""]
    assert np.allclose(pos, [[5.357, 1.5], [0.01, 0.3], [2.0, 0.02], [2.0, 2.995], [5.0, 0.5]], atol=1e-12)
    assert np.array_equal(vel, [[-0.4, -1.0], [0.2, 0.1], [0.3, 0.5], [0.0, -0.7], [1.0, 1.0]])
    # the Couette box (10 wide about x = 0.25) spans the periodic x axis: only its plates y = 0, 1 are walls
    periodic = WallTerms(load_scene(CASES / "couette.toml"))
    pos, vel = np.array([[-5.0, 0.5], [0.2, -0.01]]), np.array([[1.0, 0.0], [0.0, -1.0]])
    depth, body = periodic.reflect(pos, vel)
    assert np.allclose(depth, [0.0, 0.01]) and list(body) == ["", "plates"]
    assert pos[0, 0] == -5.0 and pos[1, 1] == pytest.approx(0.01)


def test_a_crossing_of_the_tank_is_logged_by_particle_and_a_deep_one_stops_the_run(tmp_path):
    """A wall audit: the guard mirrored back whatever crossed a box container, however far, and the log named
    only a run's first crossing, with no particle or place. Each step's deepest crossing is now logged with
    its particle, place and depth, and one deeper than half a dx is left for the run's check, which stops
    the run on it (with its state), as on a crossing of any other wall."""
    from psph.errors import NumericalError
    from psph.particles import Kind

    logs = []
    scene = load_scene(CASES / "dam_break.toml", ["domain.dx=0.1", "output.every=0"])
    with FluidDriver(scene, MPI.COMM_SELF, tmp_path, log=logs.append) as driver:
        p = driver.system.particles
        fluid = np.flatnonzero(p.owned("kind") == Kind.FLUID)
        a, b = fluid[:2]
        totals = {"wall_reflections": 0}
        p.owned("position")[a, 1] = -0.03
        driver._reflect(step=5, t=0.1, totals=totals)
        assert totals["wall_reflections"] == 1 and p.owned("position")[a, 1] == pytest.approx(0.03)
        x = p.owned("position")[a, 0]
        assert logs[-1] == (f"psph: step 5, t = 0.1: 1 fluid particle(s) crossed a wall of a box container and were "
                            f"mirrored back, the deepest 0.3 dx past the wall of body 'tank': particle gid "
                            f"{p.owned('gid')[a]}, at ({x:g}, -0.03) (history column wall_reflections)")
        p.owned("position")[b, 1] = -0.07
        driver._reflect(step=6, t=0.2, totals=totals)  # left where it is, for the run's check
        assert totals["wall_reflections"] == 1 and p.owned("position")[b, 1] == -0.07
        with pytest.raises(NumericalError, match=rf"^a fluid particle crossed the wall of body 'tank' \[step 6, "
                                                 rf"t = 0.2, particle gid {p.owned('gid')[b]}, at "
                                                 rf"\({p.owned('position')[b, 0]:g}, -0.07\)\]"):
            driver.check(6, 0.2, 1e-3)


def test_the_dam_break_diagnostics_name_the_missing_fluid_scheme():
    from psph.errors import SceneError

    with pytest.raises(SceneError, match=r"diagnostics.dam_break: needs a fluid scheme, not physics.scheme = 'none'"):
        load_scene(CASES / "dam_break.toml", ["physics.scheme=none"])
