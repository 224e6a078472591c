"""numba's on-disk cache never serves a kernel compiled from other sources (psph.compute's versioned cache
directory)."""

import os
import shutil
import subprocess
import sys

from tests.helpers import ROOT, mpi_environment

# C_i of two particles at distance 0.5 h (psph.compute.sums.concentration, which inlines smoothing.kernel_w)
SCRIPT = """
import numpy as np
from psph.compute import sums
from psph.compute.smoothing import make_kernel

kp = make_kernel("wendland_c6", 2, 1.0).params
out = np.zeros(2)
sums.concentration(np.array([[0.0, 0.0], [0.5, 0.0]]), np.ones(2), np.array([0, 1, 2]), np.array([1, 0], np.int32),
                   kp, out)
print(repr(out[0]))
"""


def test_an_edit_of_an_inlined_function_is_not_served_from_the_cache(tmp_path):
    """numba keys a function's cache on its own file's time stamp only: after an edit of smoothing.py (a
    `git pull`), sums.concentration, which inlines its kernel, was loaded from the cache compiled with the old
    one (an audit: an edit doubling the C6 gradient left sums.gradient's result as it was). The cache
    directory is named after a hash of psph.compute's sources: the edit compiles afresh."""
    shutil.copytree(ROOT / "psph", tmp_path / "src" / "psph", ignore=shutil.ignore_patterns("__pycache__"))
    env = {k: v for k, v in mpi_environment().items() if k != "NUMBA_CACHE_DIR"}
    env.update(PYTHONPATH=str(tmp_path / "src"), XDG_CACHE_HOME=str(tmp_path / "cache"))

    def concentration():
        proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=300,
                              cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return float(proc.stdout.split()[-1])

    before = concentration()
    assert concentration() == before  # from the cache
    smoothing = tmp_path / "src" / "psph" / "compute" / "smoothing.py"
    text = smoothing.read_text()
    old = "return t4 * t4 * (((32.0 * q + 25.0) * q + 8.0) * q + 1.0)"
    assert text.count(old) == 1
    smoothing.write_text(text.replace(old, "return 2.0 * t4 * t4 * (((32.0 * q + 25.0) * q + 8.0) * q + 1.0)"))
    after = concentration()
    assert after == 2.0 * before, (before, after)
    caches = sorted(p.name for p in (tmp_path / "cache" / "psph").iterdir())
    assert len(caches) == 2 and all(name.startswith("numba-") for name in caches), caches


def test_without_a_writable_user_cache_the_kernels_are_cached_in_the_temporary_directory(tmp_path):
    """Where the user's cache cannot be made (here $XDG_CACHE_HOME is a file; an audit: a read-only install run
    with no home), the cache goes to the temporary directory; numba's own choice, beside the sources, failed
    every command there ("cannot cache function ...: no locator available")."""
    (tmp_path / "not_a_directory").write_text("")
    (tmp_path / "tmp").mkdir()
    env = {k: v for k, v in mpi_environment().items() if k != "NUMBA_CACHE_DIR"}
    env.update(XDG_CACHE_HOME=str(tmp_path / "not_a_directory"), TMPDIR=str(tmp_path / "tmp"))
    proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=300,
                          cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    [user] = (tmp_path / "tmp").iterdir()
    assert user.name.startswith("psph-") and any(user.glob("numba-*/*/*.nbi")), sorted(user.rglob("*"))


def test_a_temporary_cache_directory_another_user_could_write_is_not_used(tmp_path):
    """psph's directory in the shared temporary directory, made first by someone else with group or world
    write: numba's index files there are pickles another user could plant, so the cache is not put there
    (numba's own choice then holds)."""
    (tmp_path / "not_a_directory").write_text("")
    (tmp_path / "tmp").mkdir()
    planted = tmp_path / "tmp" / f"psph-{os.getuid()}"
    planted.mkdir()
    planted.chmod(0o777)
    env = {k: v for k, v in mpi_environment().items() if k != "NUMBA_CACHE_DIR"}
    env.update(XDG_CACHE_HOME=str(tmp_path / "not_a_directory"), TMPDIR=str(tmp_path / "tmp"))
    script = "import psph.compute\nfrom numba.core import config\nprint(repr(config.CACHE_DIR))"
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300,
                          cwd=ROOT)
    assert proc.returncode == 0 and proc.stdout.strip() == "''", proc.stdout + proc.stderr
