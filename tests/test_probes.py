"""Point probes (output.probes, psph.probes): hydrostatic pressure read where it is known, dry probes nan,
refusals by key, a restart that continues probes.csv, and the same readings on 1, 2 and 3 ranks."""

import shutil

import numpy as np
import pytest
from mpi4py import MPI

from psph.drivers.fluid import FluidDriver
from psph.errors import SceneError
from psph.io.checkpoint import latest_checkpoint, read_checkpoint
from psph.io.history import read_history
from psph.scene.load import load_scene
from tests.helpers import CASES

TANK = ["domain.dx=0.05", "output.every=0", "output.history_every=10",
        "output.probes=[[1.0, 0.25], [1.0, 0.75], [0.3, 0.5], [1.0, 1.19]]"]


def test_probes_read_the_hydrostatic_pressure_and_nan_in_the_air(tmp_path):
    """Water at rest, H = 1, g = rho0 = 1: p = 1 - y at the wet probes, no velocity, nan more than a kernel
    support (0.2) above the surface."""
    scene = load_scene(CASES / "hydrostatic_tank.toml", [*TANK, "time.t_end=0.5"])
    with FluidDriver(scene, MPI.COMM_SELF, tmp_path) as driver:
        driver.run()
    rows = read_history(tmp_path / "probes.csv")
    assert len(rows) == len(read_history(tmp_path / "history.csv")) > 5
    assert list(rows[0]) == ["time"] + [f"{q}_{k}" for k in range(4) for q in "puv"]
    for row in rows:
        assert row["p_0"] == pytest.approx(0.75, abs=0.02) and row["p_1"] == pytest.approx(0.25, abs=0.02)
        assert row["p_2"] == pytest.approx(0.5, abs=0.02)
        assert max(abs(row[f"{q}_{k}"]) for q in "uv" for k in range(3)) < 0.01
        assert np.isnan(row["p_3"]) and np.isnan(row["u_3"])


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_probes_on_a_periodic_face_read_across_it(dim):
    """An audit: the interpolation took no periodic images, so probes at y = 0 and y = 1 of a periodic shear
    (the same point) read +0.22 and -0.22. A field sin(2 pi x_a) along every axis a, sampled on the box's
    faces, edges and corners and inside: both faces read the same, and the field to the interpolation's
    error."""
    from psph.diagnostics import interpolate_fluid
    from psph.simulation import build_system
    from tests.conftest import periodic_scene

    system = build_system(periodic_scene(dim=dim, n={1: 40, 2: 20, 3: 10}[dim]), MPI.COMM_SELF)
    pos = system.particles.owned("position")
    points = np.array([[0.0] * dim, [1.0] * dim, [0.25] + [1.0] * (dim - 1), [0.25] + [0.0] * (dim - 1),
                       [0.5] * dim, [0.05] * dim])
    values = interpolate_fluid(system, np.sin(2 * np.pi * pos), points)
    assert np.allclose(values[0], values[1], atol=1e-12) and np.allclose(values[2], values[3], atol=1e-12)
    # (the smoothing at the peaks, growing as h^2: 0.033 at h = 0.1 in 2-D, 0.124 at h = 0.2 in 3-D)
    assert np.abs(values - np.sin(2 * np.pi * points)).max() < {1: 0.05, 2: 0.05, 3: 0.15}[dim]


@pytest.mark.parametrize("sets,key,words", [
    (["output.probes=[[1.0, 0.5, 0.0]]"], "output.probes[0]", "expected 2 entries"),
    (["output.probes=[[0.5, 0.5], [2.5, 0.5]]"], "output.probes[1]", "outside the domain along axis 0"),
    (["physics.scheme=none", "output.probes=[[0.5, 0.5]]"], "output.probes", "probes sample a flow"),
])
def test_bad_probes_are_refused_by_key(sets, key, words):
    with pytest.raises(SceneError) as info:
        load_scene(CASES / "hydrostatic_tank.toml", sets)
    assert info.value.key == key and words in str(info.value)


def test_a_restart_continues_probes_csv(tmp_path):
    scene = load_scene(CASES / "hydrostatic_tank.toml", [*TANK, "time.t_end=0.3", "output.checkpoint_every=70"])
    with FluidDriver(scene, MPI.COMM_SELF, tmp_path / "whole") as driver:
        driver.run()
    shutil.copytree(tmp_path / "whole", tmp_path / "again")
    checkpoint = latest_checkpoint(tmp_path / "again")
    again = FluidDriver(scene, MPI.COMM_SELF, tmp_path / "again", restart=read_checkpoint(MPI.COMM_SELF, checkpoint))
    again.run()
    whole = (tmp_path / "whole" / "probes.csv").read_text()
    assert (tmp_path / "again" / "probes.csv").read_text() == whole and whole.count("\n") > 10


@pytest.mark.mpi
def test_probes_match_serial(comm, mpi_tmp_path):
    scene = load_scene(CASES / "hydrostatic_tank.toml", [*TANK, "time.t_end=0.05", "output.history_every=5"])
    readings = {}
    for name, c in (("par", comm), ("ser", MPI.COMM_SELF)):
        out = mpi_tmp_path / f"{name}{comm.rank if name == 'ser' else ''}"
        with FluidDriver(scene, c, out) as driver:
            driver.run()
        c.Barrier()
        readings[name] = np.array([list(r.values()) for r in read_history(out / "probes.csv")])
    par, ser = readings["par"], readings["ser"]
    assert par.shape == ser.shape and np.array_equal(np.isnan(par), np.isnan(ser))
    assert np.allclose(par[~np.isnan(par)], ser[~np.isnan(ser)], rtol=1e-9, atol=1e-12)
