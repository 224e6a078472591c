"""Architecture rules: compute kernels never communicate; the library never uses COMM_WORLD."""

import ast
from pathlib import Path

PSPH = Path(__file__).resolve().parents[1] / "psph"
FORBIDDEN_IN_KERNELS = {"mpi4py", "petsc4py", "h5py"}


def imported_modules(path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            yield node.module.split(".")[0]


def test_compute_kernels_import_no_mpi_petsc_or_h5py():
    files = list((PSPH / "compute").glob("*.py"))
    assert files
    for f in files:
        bad = FORBIDDEN_IN_KERNELS & set(imported_modules(f))
        assert not bad, f"{f.name} imports {bad}"


def test_only_the_command_line_touches_comm_world():
    users = [f.relative_to(PSPH).as_posix() for f in PSPH.rglob("*.py") if "COMM_WORLD" in f.read_text()]
    assert users == ["cli.py"]
