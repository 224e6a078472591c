"""Architecture rules: compute kernels never communicate; the library never uses COMM_WORLD."""

import ast
import re
from pathlib import Path

PSPH = Path(__file__).resolve().parents[1] / "psph"
FORBIDDEN_IN_KERNELS = {"mpi4py", "petsc4py", "h5py"}


def imported_modules(path, depth=1):
    """The modules `path` imports, to `depth` dotted parts (psph.compute.sums at 2: psph.compute)."""
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (".".join(a.name.split(".")[:depth]) for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            yield ".".join(node.module.split(".")[:depth])


def test_compute_kernels_import_no_mpi_petsc_or_h5py():
    """Neither directly nor through psph's own modules: a kernel module may import numpy, numba, scipy and
    other kernel modules only (a style audit: a kernel importing psph.parallel, which imports mpi4py,
    passed the first-name check)."""
    files = list((PSPH / "compute").glob("*.py"))
    assert files
    for f in files:
        bad = FORBIDDEN_IN_KERNELS & set(imported_modules(f))
        assert not bad, f"{f.name} imports {bad}"
        own = {m for m in imported_modules(f, depth=2) if m.startswith("psph") and m != "psph.compute"}
        assert not own, f"{f.name} imports {own}: kernels import only psph.compute"


def test_only_the_command_line_touches_comm_world():
    users = [f.relative_to(PSPH).as_posix() for f in PSPH.rglob("*.py")
             if re.search(r"\bCOMM_WORLD\b", f.read_text())]  # (not a launcher's OMPI_COMM_WORLD_RANK)
    assert users == ["cli.py"]
