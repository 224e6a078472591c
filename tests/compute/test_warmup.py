"""compute.warmup loads every kernel a run calls: none is compiled or loaded from numba's cache inside the
time loop (each first call costs milliseconds, a sizeable share of a short IIPS call)."""

import json
import subprocess
import sys

from tests.helpers import ROOT, mpi_environment

# In a fresh interpreter (this one has loaded every kernel already): warm up, note each kernel's
# signatures, run scenes of every kind for a step or two, print the kernels that gained one.
SCRIPT = """
import importlib, json, pkgutil, sys
from numba.core.registry import CPUDispatcher
import psph.compute
from psph.cli import main
from psph.compute.warmup import warm_up

modules = [importlib.import_module(f"psph.compute.{m.name}") for m in pkgutil.iter_modules(psph.compute.__path__)]


def dispatchers(name, value):  # module-level kernels, and those compiled per dimension (dicts of closures)
    if isinstance(value, CPUDispatcher):
        yield name, value
    elif isinstance(value, (dict, tuple)):
        for key, item in (value.items() if isinstance(value, dict) else enumerate(value)):
            yield from dispatchers(f"{name}[{key}]", item)


kernels = dict(kv for m in modules for k, v in vars(m).items() for kv in dispatchers(f"{m.__name__}.{k}", v))
warm_up(2, "wendland_c6")
before = {k: len(v.signatures) for k, v in kernels.items()}
for scene, *sets in json.loads(sys.argv[2]):
    options = [a for s in sets for a in ("--set", s)]
    if main(["run", f"cases/{scene}.toml", "--out", f"{sys.argv[1]}/{scene}", "--overwrite", "--quiet", *options]):
        raise SystemExit(f"{scene} failed")
print(json.dumps(sorted(k for k, v in kernels.items() if len(v.signatures) != before[k])))
"""

SCENES = [
    ["static_perturbed", "shifting.method=iips", "iips.max_newton=2"],
    ["static_perturbed", "shifting.method=iips", "iips.max_newton=2", "iips.operator=assembled"],
    ["static_perturbed", "shifting.method=explicit_iterative", "shifting.max_iterations=2"],
    ["kinematic_tgv", "time.t_end=0.002"],
    ["taylor_green_thesis", "time.t_end=0.002"],  # Riemann SPH-ALE, IIPS with the field update
    ["dam_break", "time.t_end=0.01"],  # clone walls, free surface, velocity shifting
    ["inclined_ellipse", "time.t_end=0.001"],  # a moving body in a free stream
]


def test_no_kernel_is_loaded_in_the_time_loop(tmp_path):
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path), json.dumps(SCENES)], capture_output=True,
                          text=True, timeout=600, cwd=ROOT, env=mpi_environment())
    assert proc.returncode == 0, proc.stderr[-3000:]
    loaded = json.loads(proc.stdout.splitlines()[-1])
    assert not loaded, f"loaded inside the time loop: {loaded}"
