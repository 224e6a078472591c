"""Free-surface detection (Marrone et al. 2010) and the shifting near a free surface (thesis eq. 6.29,
section 10.2.1): which particles are flagged in a tank, a disc, a 3-D slab and a disordered interior; the
restricted shifting velocity; IIPS with fixed surface particles; rank independence."""

from dataclasses import replace

import numpy as np
import pytest
from mpi4py import MPI

from psph.boundaries.free_surface import FreeSurface, make_free_surface
from psph.compute.free_surface import REGION, SURFACE
from psph.particles import Kind
from psph.scene.load import load_scene
from psph.scene.schema import FreeSurfaceSpec
from psph.shifting.base import measure
from psph.simulation import build_system
from tests.conftest import gather_by_gid
from tests.helpers import CASES

SLAB = """
name = "slab"
[domain]
dimension = {dim}
lower = {lower}
upper = {upper}
periodic = {periodic}
dx = 0.1
[initial]
fill_upper = {fill}
sigma_over_dx = {sigma}
[physics]
scheme = "delta_ale"
[shifting]
method = "delta_plus"
[time]
t_end = 1.0
"""


def detected(scene, comm=MPI.COMM_SELF, spec=None):
    """The system of `scene` with the free surface detected."""
    system = build_system(scene, comm)
    FreeSurface(spec or scene.free_surface).detect(system)
    return system


def owned(system, name):
    return system.particles.owned(name)


def slab(tmp_path, dim=2, sigma=0.0, rows=10):
    """A fluid layer of `rows` rows from y = 0 (10: 0.05 <= y <= 0.95) in a box 2 high, periodic along the other
    axes: free surfaces at its top and its bottom."""
    lower, upper = [0.0] * dim, [1.0] * dim
    upper[1] = 2.0
    fill = list(upper)
    fill[1] = 0.1 * rows - 0.04
    periodic = [True] * dim
    periodic[1] = False
    path = tmp_path / "slab.toml"
    path.write_text(SLAB.format(dim=dim, lower=lower, upper=upper, periodic=str(periodic).lower(), fill=fill,
                                sigma=sigma))
    return load_scene(path)


@pytest.mark.parametrize("dim", [2, 3])
def test_a_slab_has_its_top_and_bottom_rows_at_the_surface(tmp_path, dim):
    system = detected(slab(tmp_path, dim))
    y, flag = owned(system, "position")[:, 1], owned(system, "free_surface")
    assert np.allclose(np.unique(y), 0.05 + 0.1 * np.arange(10))
    edge = np.isclose(y, 0.05) | np.isclose(y, 0.95)
    assert np.all(flag[edge] == SURFACE) and not np.any(flag[~edge] == SURFACE)
    # within the support (2h = 4 dx) of a surface row: rows 1-3 deep; the slab is 10 rows thick, so the
    # two middle rows (4 dx from either surface: the support's edge) are the only candidates for interior
    depth = np.minimum(y - 0.05, 0.95 - y)
    assert np.all(flag[(depth > 0.05) & (depth < 0.35)] == REGION)
    assert np.all(flag[depth > 0.4 - 1e-9] == 0)  # exactly a support from the surface: outside it
    normal = owned(system, "surface_normal")
    expected = np.where(y > 0.5, 1.0, -1.0)  # the region takes its surface's normal; the interior has none
    near = flag > 0
    assert np.allclose(normal[near, 1], expected[near], atol=1e-12) and not np.any(normal[~near])
    lam = owned(system, "surface_lambda")
    assert np.allclose(lam[edge], lam[edge][0])
    # lambda_min of M_i itself (thesis eq. 6.28 prints the inverse, whose smallest eigenvalue is 1 inside and
    # about 1 at a flat surface too, where M's eigenvalues are 1 and 1/2): the thresholds 0.2 / 0.75 then part
    # the surface row from the interior
    assert 0.45 < lam[edge][0] < 0.55 and np.allclose(lam[depth > 0.4 - 1e-9], 1.0, atol=0.01), lam


def test_a_tank_flags_its_surface_row_and_nothing_along_its_walls():
    scene = load_scene(CASES / "hydrostatic_tank.toml", ["domain.dx=0.05", "shifting.method=delta_plus"])
    system = detected(scene)
    p = system.particles
    fluid = owned(system, "kind") == Kind.FLUID
    pos, flag = owned(system, "position")[fluid], owned(system, "free_surface")[fluid]
    top = np.isclose(pos[:, 1], pos[:, 1].max())
    assert np.all(flag[top] == SURFACE) and not np.any(flag[~top] == SURFACE)  # the clone walls fill the support
    assert np.all(flag[pos[:, 1] < 1.0 - 0.2 - 1e-9] == 0)  # deeper than the support: interior
    assert np.all(owned(system, "free_surface")[~fluid] == 0) and p.n_owned > fluid.sum()


def test_the_rim_of_a_disc_is_its_surface_with_outward_normals():
    scene = load_scene(CASES / "elliptical_drop.toml", ["domain.dx=0.1", "shifting.method=delta_plus"])
    system = detected(scene)
    pos, flag = owned(system, "position"), owned(system, "free_surface")
    r = np.linalg.norm(pos, axis=1)
    surface = flag == SURFACE
    # only the outermost particles, and all the way round (every 20 degrees holds some)
    assert r[surface].min() > 1.0 - 1.5 * 0.1 and not np.any(surface[r < 1.0 - 1.5 * 0.1])
    angles = np.degrees(np.arctan2(pos[surface, 1], pos[surface, 0]))
    assert len(np.unique(np.floor((angles + 180.0) / 20.0))) == 18
    # every lattice particle within half a spacing of the circle is found
    assert np.all(surface[r > 1.0 - 0.05])
    radial = pos[surface] / r[surface, None]
    assert np.all((owned(system, "surface_normal")[surface] * radial).sum(axis=1) > 0.8)
    assert np.all(flag[r < r[surface].min() - 0.4 - 1e-9] == 0)  # beyond a support from the surface
    assert np.all(flag[r > 1.0 - 0.4] > 0)


def test_a_disordered_interior_has_no_surface(tmp_path):
    scene = load_scene(CASES / "static_perturbed.toml", ["initial.sigma_over_dx=0.25", "domain.dx=0.05"])
    system = detected(scene, spec=FreeSurfaceSpec())
    assert not np.any(owned(system, "free_surface"))
    # lambda alone would not do: the disorder gives candidates, and the scan region clears them
    assert np.count_nonzero(owned(system, "surface_lambda") <= 0.75) > 5


def test_a_smaller_scan_region_finds_a_narrow_air_gap(tmp_path):
    """Two layers 3 dx apart face to face (the slab without rows 4 and 5): the faces' lambda is an interior
    particle's about, and with the scan region of radius h = 2 dx the other layer fills it (a free-surface
    audit: none of the faces found); at free_surface.scan_radius = 0.67 (Marrone et al.'s h = 1.33 dx) every
    face particle is a surface, and the outer surfaces stay as they were."""
    scene = slab(tmp_path)
    found = {}
    for radius in (1.0, 0.67):
        system = build_system(scene, MPI.COMM_SELF)
        p = system.particles
        keep = ~np.isclose(owned(system, "position")[:, 1], 0.45) & ~np.isclose(owned(system, "position")[:, 1], 0.55)
        p.set_owned({name: arr[keep] for name, arr in p.owned_arrays().items()})
        system.rebuild()
        FreeSurface(FreeSurfaceSpec(scan_radius=radius)).detect(system)
        y, flag = owned(system, "position")[:, 1], owned(system, "free_surface")
        faces = np.isclose(y, 0.35) | np.isclose(y, 0.65)
        outer = np.isclose(y, 0.05) | np.isclose(y, 0.95)
        assert faces.sum() == outer.sum() == 20 and np.all(flag[outer] == SURFACE)
        assert not np.any(flag[~faces & ~outer] == SURFACE)
        found[radius] = int(np.count_nonzero(flag[faces] == SURFACE))
    assert found == {1.0: 0, 0.67: 20}


def test_an_isolated_particle_is_a_surface(tmp_path):
    scene = slab(tmp_path)
    system = build_system(scene, MPI.COMM_SELF)
    p = system.particles
    k = int(np.argmax(owned(system, "position")[:, 1]))
    p.owned("position")[k, 1] = 1.8  # far above the slab
    system.rebuild()
    FreeSurface(scene.free_surface).detect(system)
    k = int(np.argmax(owned(system, "position")[:, 1]))
    assert owned(system, "surface_lambda")[k] == 0.0 and owned(system, "free_surface")[k] == SURFACE


def test_the_restricted_shift_has_no_normal_component_near_the_surface(tmp_path):
    scene = slab(tmp_path, sigma=0.1)
    system = detected(scene)
    surface = FreeSurface(scene.free_surface)
    rng = np.random.default_rng(3)
    du = rng.standard_normal((system.particles.n_owned, 2))
    before = du.copy()
    surface.restrict(system, du)
    flag, lam, normal = (owned(system, name) for name in ("free_surface", "surface_lambda", "surface_normal"))
    near = flag > 0
    assert near.any() and (~near).any()
    assert np.array_equal(du[~near], before[~near])
    low = near & (lam < 0.4)
    assert np.all(du[low] == 0.0)
    tangential = near & ~low
    assert tangential.sum() > 20
    assert np.abs((du[tangential] * normal[tangential]).sum(axis=1)).max() < 1e-14
    # the tangential part is kept
    assert np.allclose(du[tangential], before[tangential] - (before[tangential] * normal[tangential]).sum(
        axis=1)[:, None] * normal[tangential])


def test_make_free_surface_only_where_a_shifting_meets_a_free_surface():
    drop = CASES / "elliptical_drop.toml"
    assert not make_free_surface(load_scene(drop)).active  # shifting none
    assert make_free_surface(load_scene(drop, ["shifting.method=delta_plus"])).active
    assert make_free_surface(load_scene(drop, ["shifting.method=iips"])).active
    assert not make_free_surface(load_scene(CASES / "lid_driven_cavity.toml")).active  # no free surface


def test_iips_keeps_the_surface_region_in_place(tmp_path):
    from psph.shifting.iips import ImplicitShifting

    scene = slab(tmp_path, sigma=0.1)
    system = build_system(scene, MPI.COMM_SELF)
    surface = FreeSurface(scene.free_surface)
    surface.detect(system)
    start = measure(system, "volume", surface.interior(system))[2]
    iips = ImplicitShifting(scene.iips, system.comm, surface=surface)
    before = dict(zip(owned(system, "gid"), owned(system, "position").copy()))
    report = iips.correct(system)
    iips.destroy()
    flag = owned(system, "free_surface")
    moved = np.array([np.linalg.norm(x - before[g]) for g, x in zip(owned(system, "gid"), owned(system, "position"))])
    assert np.all(moved[flag > 0] == 0.0) and moved[flag == 0].max() > 0.0
    assert report.iterations == 20 and report.Linf_grad_c < 0.1 * start


def test_a_sheet_has_no_interior_and_no_iips_unknowns(tmp_path):
    """Seven rows: every row is within a support of a surface, so IIPS has nothing to move; the middle row's
    region normal, balanced between the two surfaces, is undefined (zero), and so is its shift."""
    from psph.shifting.iips import ImplicitShifting

    scene = slab(tmp_path, rows=7)
    system = build_system(scene, MPI.COMM_SELF)
    surface = FreeSurface(scene.free_surface)
    iips = ImplicitShifting(scene.iips, system.comm, surface=surface)
    report = iips.correct(system)
    iips.destroy()
    assert report.iterations == 0 and "no IIPS unknowns" in report.message
    y, flag = owned(system, "position")[:, 1], owned(system, "free_surface")
    assert np.all(flag > 0)
    middle = np.isclose(y, 0.35)
    assert not np.any(owned(system, "surface_normal")[middle])
    du = np.ones((system.particles.n_owned, 2))
    surface.restrict(system, du)
    assert not np.any(du[middle]) and np.allclose(du[~middle], [1.0, 0.0], atol=1e-14)


def test_iips_follows_unknowns_that_change_without_a_rebuild(tmp_path):
    """Turning the top row into walls moves the surface region (no neighbour-list rebuild): the next IIPS call
    builds its matrix over the new unknowns."""
    from psph.shifting.iips import ImplicitShifting

    scene = slab(tmp_path, sigma=0.05, rows=14)
    system = build_system(scene, MPI.COMM_SELF)
    surface = FreeSurface(scene.free_surface)
    iips = ImplicitShifting(replace(scene.iips, max_newton=2), system.comm, surface=surface)
    iips.correct(system)
    before = iips.mat.getSize()[0]
    assert before == 2 * np.count_nonzero(surface.unknowns(system)) > 0
    rebuilds = system.rebuilds
    p = system.particles
    top = p["position"][:, 1] > 1.0  # the top four rows, a support deep: the rows below get full supports
    p["kind"][top] = Kind.WALL
    iips.correct(system)
    assert system.rebuilds == rebuilds
    after = iips.mat.getSize()[0]
    assert after == 2 * np.count_nonzero(surface.unknowns(system)) > before
    iips.destroy()


def test_psph_info_describes_the_detection():
    from tests.helpers import run_psph

    res = run_psph("info", CASES / "elliptical_drop.toml", "--set", "shifting.method=delta_plus")
    assert res.returncode == 0, res.stderr
    assert "free-surface detection (Marrone et al. 2010)" in res.stdout


@pytest.mark.mpi
def test_detection_is_rank_independent():
    comm = MPI.COMM_WORLD
    scene = load_scene(CASES / "elliptical_drop.toml", ["domain.dx=0.05", "shifting.method=delta_plus",
                                                       "initial.sigma_over_dx=0.1"])
    system = detected(scene, comm)
    gid = owned(system, "gid")
    _, flags = gather_by_gid(comm, gid, owned(system, "free_surface"))
    _, normals = gather_by_gid(comm, gid, owned(system, "surface_normal"))
    serial = detected(scene)
    _, flags1 = gather_by_gid(MPI.COMM_SELF, owned(serial, "gid"), owned(serial, "free_surface"))
    _, normals1 = gather_by_gid(MPI.COMM_SELF, owned(serial, "gid"), owned(serial, "surface_normal"))
    assert np.count_nonzero(flags1 == SURFACE) > 50
    assert np.array_equal(flags, flags1) and np.allclose(normals, normals1, atol=1e-12)


def drop_run(tmp_path, monkeypatch, restricted):
    """The drop at R/dx = 10 with delta+ to t A0 = 0.5: with the free surface detected and the shift
    restricted, or (restricted=False) with delta+ left to push the rim outward."""
    import psph.schemes.delta_ale as delta_ale
    from psph.boundaries.free_surface import NoFreeSurface
    from psph.drivers.fluid import FluidDriver

    if not restricted:
        monkeypatch.setattr(delta_ale, "make_free_surface", lambda scene: NoFreeSurface())
    scene = load_scene(CASES / "elliptical_drop.toml", ["domain.dx=0.1", "packing.iterations=300",
                                                       "shifting.method=delta_plus", "time.t_end=0.5"])
    return FluidDriver(scene, MPI.COMM_SELF, tmp_path).run()


def test_the_restriction_is_what_lets_delta_plus_run_a_drop(tmp_path, monkeypatch):
    from psph.errors import NumericalError
    from psph.io.history import read_history

    drop_run(tmp_path / "restricted", monkeypatch, True)
    history = read_history(tmp_path / "restricted" / "history.csv")
    assert history[-1]["time"] == pytest.approx(0.5)
    assert max(r["semi_axis_error"] for r in history) < 0.01  # measured 0.0048
    assert all(r["surface_particles"] >= 2 * np.pi * 10 * 0.9 for r in history)  # the rim, all along
    with pytest.raises(NumericalError, match="density left the weakly compressible range"):
        drop_run(tmp_path / "unrestricted", monkeypatch, False)  # measured: at step 145, t = 0.27


def test_the_pre_procedure_keeps_a_drop_rim_in_place(tmp_path):
    """iips.pre_newton with shifting none: the pre-procedure detects the surface for itself and leaves the
    region where it was; the run itself makes no detection."""
    from psph.drivers.fluid import FluidDriver
    from psph.initial import create_particles

    scene = load_scene(CASES / "elliptical_drop.toml", ["domain.dx=0.1", "packing.iterations=0",
                                                       "initial.sigma_over_dx=0.1", "iips.pre_newton=5"])
    start = create_particles(scene, MPI.COMM_SELF)
    start = dict(zip(start.owned("gid"), start.owned("position").copy()))
    driver = FluidDriver(scene, MPI.COMM_SELF, tmp_path)
    assert not driver.scheme.surface.active and np.isfinite(driver.pre["linf"])
    p = driver.system.particles
    moved = np.array([np.linalg.norm(x - start[g]) for g, x in zip(p.owned("gid"), p.owned("position"))])
    flag = p.owned("free_surface")
    assert np.count_nonzero(flag == SURFACE) > 50 and np.all(moved[flag > 0] == 0.0) and moved.max() > 0.0
