#!/usr/bin/env bash
# Set up psph on a fresh Debian machine (idempotent): system packages, .venv, editable install.
#   run_scripts/setup.sh          # quiet if everything is already there
# Debian's packages give PETSc/petsc4py, OpenMPI/mpi4py, parallel h5py, numba and numpy 1.x; the venv
# sees them (--system-site-packages) and adds psph with its test tools from PyPI.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$PSPH_ROOT"

packages=(python3 python3-venv python3-dev python3-pip python3-petsc4py python3-mpi4py python3-numba
          python3-h5py-mpi python3-numpy python3-scipy python3-matplotlib python3-sympy openmpi-bin
          libopenmpi-dev)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing Debian packages: ${missing[*]}"
    sudo=""
    [ "$(id -u)" = 0 ] || sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    # PETSC_DIR is found from the installed layout: look again now that PETSc is there
    source "$PSPH_ROOT/run_scripts/env.sh"
fi

if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv (with system site packages)"
    /usr/bin/python3 -m venv --system-site-packages .venv
fi

# reinstall only when the project metadata changed
stamp=.venv/.psph-installed
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    echo "setup: installing psph (editable) with test tools"
    .venv/bin/python -m pip install -q --disable-pip-version-check -e ".[test]"
    echo "$want" > "$stamp"
fi

# the stack must import together (fails loudly here rather than inside a test)
.venv/bin/python - <<'PY'
import numpy, numba, mpi4py, h5py, petsc4py
assert numpy.__version__.startswith("1."), f"numpy {numpy.__version__}: petsc4py/h5py need numpy 1.x"
assert h5py.get_config().mpi, "h5py lacks MPI support (install python3-h5py-mpi)"
petsc4py.init([])
from petsc4py import PETSc
PY
