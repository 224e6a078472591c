"""Memory: the peak a run reports, and the estimate `psph info` prints and `psph run` checks (the estimate's
constants against measured peaks: run_scripts/bench_memory.py)."""

import math
import subprocess
import sys

import pytest
from mpi4py import MPI

from psph.errors import SceneError
from psph.scene.load import load_scene
from psph.shifting.iips import SHIFT_FIELD, ImplicitShifting
from psph.shifting.iips_operator import AssembledOperator
from psph.simulation import BASE_BYTES, check_resources, estimate_resources, iips_assembled, machine_memory
from tests.helpers import CASES
from tests.shifting.test_iips import petsc_options

SCENE = CASES / "static_perturbed.toml"
IIPS = ["shifting.method=iips"]


PROBE = """
import numpy as np
from psph.profiling import memory
block = 200 * 2**20
before, _ = memory()
data = np.ones(block // 8)  # written, so resident
during, peak = memory()
assert during - before > 0.9 * block and peak - before > 0.9 * block, (before, during, peak)
del data  # a block this large is mapped on its own, and given back when freed
after, peak_after = memory()
assert after < during - 0.9 * block and peak_after > during - 0.05 * block, (during, after, peak, peak_after)
print("ok")
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the resident size is read from Linux's /proc")
def test_memory_follows_an_allocation_and_its_release():
    """In a process of its own: a test worker's heap holds what earlier tests freed."""
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


RELEASE_PROBE = """
import numpy as np
from psph.profiling import memory
from psph.solvers.petsc import petsc
petsc()  # loads PETSc's libraries, SuperLU_DIST's among them on Debian
before, _ = memory()
data = np.empty((50 * 2**20 // 8, 1)); data[:] = 1.0  # 50 MiB, written
during, _ = memory()
del data
after, _ = memory()
assert during - before > 45 * 2**20 and during - after > 45 * 2**20, (before, during, after)
print("ok")
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the resident size is read from Linux's /proc")
def test_freed_memory_is_given_back_once_petsc_is_loaded():
    """SuperLU_DIST's library constructor turns off glibc's mapping of large blocks and the heap's trimming;
    psph turns them on again (solvers.petsc.release_freed_memory), so a large array's memory leaves the
    process when it is freed. In a process of its own."""
    done = subprocess.run([sys.executable, "-c", RELEASE_PROBE], capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


@pytest.mark.parametrize("sets,options,assembled", [
    ([], {}, False),
    ([], {"iips_pc_type": "jacobi"}, False),
    ([], {"iips_pc_type": "hypre"}, True),
    ([], {"iips_mat_type": "baij"}, True),
    ([], {"iips_pc_jacobi_type": "rowsum"}, True),
    (["iips.operator=assembled"], {}, True),
    (["iips.operator=matrix_free"], {"iips_pc_type": "none"}, False),
])
def test_the_estimate_counts_the_iips_operator_the_run_builds(sets, options, assembled):
    """From PETSc's options database (whatever set it: the command line, PETSC_OPTIONS, an options file),
    as the IIPS solver then builds it."""
    scene = load_scene(SCENE, IIPS + sets)
    with petsc_options(**options):
        assert iips_assembled(scene) is assembled
        shifting = ImplicitShifting(scene.iips, MPI.COMM_SELF)
        try:
            assert isinstance(shifting.operator, AssembledOperator) is assembled
        finally:
            shifting.destroy()


def test_the_estimate_counts_an_iips_pre_procedure_and_nothing_without_iips():
    kinematic = CASES / "kinematic_tgv.toml"
    with petsc_options(iips_pc_type="hypre"):
        assert iips_assembled(load_scene(kinematic, ["shifting.method=explicit_iterative"]))  # pre_newton = 100
        assert not iips_assembled(load_scene(SCENE, ["shifting.method=explicit_iterative"]))


def test_a_rebuilt_iips_matrix_is_freed_before_its_successor_is_built(monkeypatch):
    """After a neighbour-list rebuild the assembled matrix of the last structure, which the solver used, is
    gone (its arrays freed) before the new one is built: the KSP held it through the build, so two matrices
    shared the peak (static IIPS at 160 000 particles in 2-D, one rank: 1536 MiB instead of 1083)."""
    import weakref

    from psph.simulation import build_system
    from psph.solvers.aij import FixedPatternMatrix
    from tests.conftest import periodic_scene

    scene = periodic_scene(n=12, sigma=0.1, shifting={"method": "iips"}, iips={"operator": "assembled"})
    earlier, alive_at_build = [], []
    build = FixedPatternMatrix.__init__

    def tracked(matrix, *args, **kwargs):
        alive_at_build.append(sum(ref() is not None for ref in earlier))
        build(matrix, *args, **kwargs)
        earlier.extend(weakref.ref(a) for a in matrix.arrays)

    monkeypatch.setattr(FixedPatternMatrix, "__init__", tracked)
    system = build_system(scene, MPI.COMM_SELF)
    shifting = ImplicitShifting(scene.iips, MPI.COMM_SELF)
    system.particles.add_field(SHIFT_FIELD)
    try:
        for _ in range(2):
            grad, _, _ = shifting.measure(system)
            assert shifting.newton_iteration(system, grad) > 0  # the KSP set up on this structure's matrix
            system.rebuild()
        shifting.assemble(system)
    finally:
        shifting.destroy()
        system.close()
    assert len(earlier) == 9 and alive_at_build == [0, 0, 0]


def test_the_estimate_counts_ranks_and_the_assembled_matrix():
    scene = load_scene(SCENE, IIPS + ["domain.dx=0.0025"])
    n, one, per_particle = estimate_resources(scene)
    _, two, per_particle_2 = estimate_resources(scene, ranks=2)
    _, aij, per_particle_aij = estimate_resources(scene, assembled=True)
    assert n == 160_000 and one == pytest.approx(n * per_particle + BASE_BYTES)
    assert two - one > BASE_BYTES and per_particle_2 > per_particle  # a second base, and a longer halo boundary
    # the peaks bench_memory.py measured at 160 000 particles on one rank: 459 MiB matrix-free, 965 MiB assembled
    mib = 2**20
    assert 459 * mib <= one <= 1.5 * 459 * mib and 965 * mib <= aij <= 1.5 * 965 * mib


SHELF = {"name": "shelf", "domain": {"dimension": 2, "lower": [0.0, 0.0], "upper": [4.0, 2.0],
                                     "periodic": [False, False], "dx": 0.1, "outflow": ["x+"],
                                     "outflow_buffer": True},
         "initial": {"fill_lower": [0.0, 0.4], "fill_upper": [4.0, 0.85]},
         "physics": {"scheme": "delta_ale", "gravity": [0.0, -1.0]}, "time": {"t_end": 0.01},
         "bodies": [{"name": "plate", "shape": "rectangle", "center": [2.5, 0.2], "size": [5.0, 0.4],
                     "wall": "free_slip"}]}
# a tank with ten baffles rising from its floor inside the domain, the water between the wall and the first
BAFFLES = {"name": "baffles", "domain": {"dimension": 2, "lower": [0.0, 0.0], "upper": [4.0, 2.0],
                                         "periodic": [False, False], "dx": 0.02},
           "initial": {"fill_upper": [0.2, 0.5], "pressure": "hydrostatic"},
           "physics": {"scheme": "delta_ale", "gravity": [0.0, -1.0]}, "shifting": {"method": "none"},
           "time": {"t_end": 0.01},
           "bodies": [{"name": "tank", "shape": "polygon", "wall": "no_slip", "vertices": [
               [0.0, 0.0], *[v for k in range(10) for v in ([0.2 + 0.38 * k, 0.0], [0.2 + 0.38 * k, 1.8],
                                                           [0.36 + 0.38 * k, 1.8], [0.36 + 0.38 * k, 0.0])],
               [4.0, 0.0], [4.0, 2.0], [0.0, 2.0]]}]}
CUBE = {"name": "cube", "domain": {"dimension": 3, "lower": [0.0] * 3, "upper": [1.0] * 3, "periodic": [False] * 3,
                                   "dx": 0.125},
        "initial": {"fill_upper": [0.3125] * 3}, "physics": {"scheme": "delta_ale"}, "time": {"t_end": 0.01}}


@pytest.mark.parametrize("scene", ["dam_break", "tank", "shelf", "cube", "baffles"])
def test_the_estimate_counts_the_fill_not_the_whole_domain_and_bounds_the_start(tmp_path, scene):
    """A new user's audit: a 3-D column filling an eighth of its box was estimated at the box's lattice (6400
    against 800). Without an inflow the particles can only leave, so the fill's lattice and the solids bound
    them (initial_particles_bound), from above whatever the scene (a review: the first version counted a box
    whose faces lie on lattice nodes a row short per axis, 8 for 27, and missed the solids and the outflow
    buffer past the domain's faces; another, a container's walls inside the domain, counted only along its
    faces: the baffles 6326 for 9842): the dam break's column 8305 against 5932 run (25 800 before)."""
    from psph.drivers.fluid import FluidDriver
    from psph.scene.load import scene_from_table
    from psph.simulation import initial_particles_bound

    sc = {"dam_break": lambda: load_scene(CASES / "dam_break.toml", ["packing.iterations=0"]),
          "tank": lambda: load_scene(CASES / "hydrostatic_tank.toml", ["domain.dx=0.1",
                                                                       "initial.fill_upper=[2.0, 0.45]"]),
          "shelf": lambda: scene_from_table(SHELF), "cube": lambda: scene_from_table(CUBE),
          "baffles": lambda: scene_from_table(BAFFLES)}[scene]()
    with FluidDriver(sc, MPI.COMM_SELF, tmp_path, log=lambda message: None) as driver:  # (its outflow buffer too)
        actual = driver.system.n_global
        fluid = int((driver.system.particles.owned("kind") == 0).sum())
    bound = initial_particles_bound(sc)
    # (a container's sides are counted each with a strip past both its ends, a support and a node (5 dx) wide:
    # the coarse tank's (dx = 0.1) add up to 2.1 times its particles, the baffles' to 2.1, each baffle's two
    # strips overlapping in its solid 8 dx across)
    assert actual <= bound <= {"tank": 2.5, "baffles": 2.5}.get(scene, 2.0) * actual, (actual, bound)
    n = estimate_resources(sc)[0]
    assert n == min(bound, sc.domain.estimated_particles()) and fluid <= n
    if scene in ("dam_break", "cube"):
        assert n < sc.domain.estimated_particles() / 2


def test_an_assembled_matrix_that_would_not_fit_is_refused_before_the_run():
    """A scene that fits matrix-free but not with the assembled matrix that -iips_pc_type hypre needs; on a
    cluster, what counts is this machine's share of the ranks."""
    scene = load_scene(SCENE, IIPS + ["domain.dx=0.0025"])
    per_mf, per_aij = (estimate_resources(scene, assembled=a)[2] for a in (False, True))
    n = 0.8 * machine_memory() / math.sqrt(per_mf * per_aij)  # between the two limits
    big = load_scene(SCENE, IIPS + [f"domain.dx={1 / round(math.sqrt(n))!r}"])
    check_resources(big)
    with petsc_options(iips_pc_type="hypre"):
        with pytest.raises(SceneError, match="domain.dx: .* particles need about"):
            check_resources(big)
        check_resources(big, ranks=4, node_ranks=1)  # a quarter of it here
        with pytest.raises(SceneError, match=r"on this machine \(3 of the run's 4 ranks\)"):
            check_resources(big, ranks=4, node_ranks=3)


def test_one_nodes_memory_refusal_stops_every_rank(tmp_path):
    """A parallel audit: each node judges its own memory, and a refusal by some ranks only (a node with less
    memory, or more of the ranks) left the others waiting in the next collective, silently, for ever. Rank 1
    is given a 256 MiB machine: both ranks stop with the one-line refusal, exit 2."""
    import subprocess
    import sys

    from tests.helpers import ROOT, mpi_environment

    script = tmp_path / "small_node.py"
    script.write_text("import sys\nfrom mpi4py import MPI\nimport psph.simulation\n"
                      "if MPI.COMM_WORLD.rank == 1:\n    psph.simulation.machine_memory = lambda: 2**28\n"
                      "from psph.cli import main\nsys.exit(main(sys.argv[1:]))\n")
    res = subprocess.run(["mpiexec", "-n", "2", "--oversubscribe", sys.executable, str(script), "run",
                          str(ROOT / "cases" / "couette.toml"), "--set", "time.t_end=0.01", "--out",
                          str(tmp_path / "out"), "--quiet"], capture_output=True, text=True, timeout=120, cwd=ROOT,
                         env=mpi_environment())
    assert res.returncode == 2, res.stderr
    lines = [line for line in res.stderr.splitlines() if line.startswith("psph:")]
    assert lines == [lines[0]] and "domain.dx: 200 particles need about" in lines[0] and \
        "this machine's 0.25 GiB" in lines[0], res.stderr
