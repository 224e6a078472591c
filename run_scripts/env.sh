# Environment psph needs on Debian's PETSc/OpenMPI stack; sourced by the other run_scripts.
if [ -z "${PETSC_DIR:-}" ] && [ ! -e /usr/lib/petsc ]; then
    for d in /usr/lib/petscdir/petsc*/x86_64-linux-gnu-real /usr/lib/petscdir/petsc*/*-real; do
        if [ -d "$d" ]; then export PETSC_DIR="$d"; break; fi
    done
fi
if [ "$(id -u)" = 0 ]; then
    export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
fi
export H5PY_ALWAYS_USE_MPI=1          # Debian's h5py: use the MPI build outside mpiexec too
# one OpenBLAS thread per rank (PETSc's dot products and norms): its threads took 15-50% of an IIPS solve on a
# loaded machine, and compete with the other ranks for the cores (a benchmark audit)
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
export OMPI_MCA_rmaps_base_oversubscribe=1
export OMPI_MCA_btl_vader_single_copy_mechanism=none   # containers without ptrace permissions
export PSPH_ROOT="${PSPH_ROOT:-$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)}"
export PSPH_PYTHON="$PSPH_ROOT/.venv/bin/python"
