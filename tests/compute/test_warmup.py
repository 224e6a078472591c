"""compute.warmup loads every kernel a run calls: none is compiled or loaded from numba's cache inside the
time loop (each first call costs milliseconds, a sizeable share of a short IIPS call)."""

import json
import subprocess
import sys

import pytest

from tests.helpers import ROOT, mpi_environment

# In a fresh interpreter (this one has loaded every kernel already): run scenes of every kind, dimension and
# kernel for a step or two; note each kernel's signatures right after the run's own warm-up (wrapped) and
# print, per scene, the kernels that gained one later.
SCRIPT = """
import importlib, json, pkgutil, sys
from numba.core.registry import CPUDispatcher
import psph.compute
import psph.simulation
from psph.cli import main

modules = [importlib.import_module(f"psph.compute.{m.name}") for m in pkgutil.iter_modules(psph.compute.__path__)]


def dispatchers(name, value):  # module-level kernels, and those compiled per dimension (dicts of closures)
    if isinstance(value, CPUDispatcher):
        yield name, value
    elif isinstance(value, (dict, tuple)):
        for key, item in (value.items() if isinstance(value, dict) else enumerate(value)):
            yield from dispatchers(f"{name}[{key}]", item)


kernels = dict(kv for m in modules for k, v in vars(m).items() for kv in dispatchers(f"{m.__name__}.{k}", v))
signatures = lambda: {k: len(v.signatures) for k, v in kernels.items()}  # noqa: E731
after_warm_up = []
warm_up = psph.simulation.warm_up


def noted_warm_up(*args):
    warm_up(*args)
    after_warm_up.append(signatures())


psph.simulation.warm_up = noted_warm_up
loaded = {}
for number, (scene, *sets) in enumerate(json.loads(sys.argv[2])):
    options = [a for s in sets for a in ("--set", s)]
    if main(["run", f"cases/{scene}.toml", "--out", f"{sys.argv[1]}/{number}", "--quiet", *options]):
        raise SystemExit(f"{scene} {sets} failed")
    if len(after_warm_up) != number + 1:
        raise SystemExit(f"{scene} {sets}: the run did not warm up")
    before, now = after_warm_up[-1], signatures()
    gained = sorted(k for k in kernels if now[k] != before[k])
    if gained:
        loaded[" ".join([scene, *sets])] = gained
print(json.dumps(loaded))
"""

# a 1-D and a 3-D periodic box (with C2 and the cubic spline)
BOX_1D = ["domain.dimension=1", "domain.lower=[0.0]", "domain.upper=[1.0]", "domain.periodic=[true]", "domain.dx=0.01"]
BOX_3D = ["domain.dimension=3", "domain.lower=[0.0, 0.0, 0.0]", "domain.upper=[1.0, 1.0, 1.0]",
          "domain.periodic=[true, true, true]", "domain.dx=0.125"]
# each run in its own interpreter, so that it is the first to call any kernel: a kernel that its scene's warm-up
# leaves out (psph.simulation.warm_up_parts) is loaded in its time loop, even if another scene's warm-up has it
RUNS = [
    ["static_perturbed", "shifting.method=iips", "iips.max_newton=2"],
    ["static_perturbed", "shifting.method=iips", "iips.max_newton=2", "iips.operator=assembled"],
    ["static_perturbed", "shifting.method=explicit_iterative", "shifting.max_iterations=2"],
    ["kinematic_tgv", "time.t_end=0.002"],
    ["taylor_green", "time.t_end=0.002"],
    ["taylor_green", "time.t_end=0.002", "shifting.method=none", "iips.update=none"],
    ["taylor_green", "time.t_end=0.002", "iips.procedure=A"],  # IIPS at every step, its MLS update
    ["taylor_green_thesis", "time.t_end=0.002"],  # Riemann SPH-ALE, IIPS with the field update
    ["dam_break", "time.t_end=0.01"],  # clone walls, free surface, velocity shifting
    ["inclined_ellipse", "time.t_end=0.001"],  # a moving body in a free stream
    ["lid_driven_cavity", "time.t_end=0.01"],  # IIPS with NFTS beside walls
    ["impinging_jet", "time.t_end=0.01"],  # inflow, outflow, free surface
    # the buffers extrapolated from the fluid (a review found them compiled in the loop), ghost walls
    ["impinging_jet", "time.t_end=0.01", "inflow.0.density=extrapolated", "domain.outflow_buffer=true"],
    ["hydrostatic_tank", "time.t_end=0.01", "bodies.0.model=ghost"],
    ["static_perturbed", "shifting.method=iips", "iips.max_newton=2", "domain.kernel=wendland_c2", *BOX_1D],
    # (one iteration: the cubic spline's second at dx = 0.125 leaves the box worse than it started, and stops)
    ["static_perturbed", "shifting.method=iips", "iips.max_newton=1", "domain.kernel=cubic_spline", *BOX_3D],
    ["static_perturbed", "shifting.method=explicit_iterative", "shifting.max_iterations=2", *BOX_3D],
]


@pytest.mark.parametrize("run", RUNS, ids=[" ".join(r) for r in RUNS])
def test_no_kernel_is_loaded_in_the_time_loop(run, tmp_path):
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path), json.dumps([run])], capture_output=True,
                          text=True, timeout=600, cwd=ROOT, env=mpi_environment())
    assert proc.returncode == 0, proc.stderr[-3000:]
    loaded = json.loads(proc.stdout.splitlines()[-1])
    assert not loaded, f"loaded after the run's warm-up: {loaded}"
