#!/usr/bin/env bash
# Set up if needed, then run the test suite: everything on 1 rank, then the MPI tests on 2 and 3 ranks.
#   run_scripts/test.sh [extra pytest arguments for the serial run, e.g. -n 0 for one process]
# The serial run spreads its tests over two pytest-xdist workers (the machines have two cores); on a fresh
# checkout the whole takes 10 to 30 minutes (README).
set -euo pipefail
"$(dirname "${BASH_SOURCE[0]}")/setup.sh"
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$PSPH_ROOT"
py="$PSPH_PYTHON"

# On a fresh checkout every test process compiled the numba kernels it met before another had cached them
# (CI: 18 instead of 10 minutes for the serial part); compiled once here, two processes sharing the work,
# they are loaded from numba's cache after (seconds when already cached)
echo "== numba kernels: compiling once (cached for every test process)"
"$py" -m psph.compute.warmup 1 &
first=$!
"$py" -m psph.compute.warmup 2 3
wait "$first"

echo "== serial tests (MPI tests included, on 1 rank; two workers)"
# one test at a time to each worker, the tests marked `long` first (tests/conftest.py): they share the long ones
"$py" -m pytest --with-mpi -n 2 --maxschedchunk 1 "$@"

mpi_tests() {
    # rank 0 reports; the other ranks' failures still print (tests/conftest.py aborts all ranks on a failure)
    timeout 900 mpiexec -n "$1" --oversubscribe bash -c \
        'if [ "${OMPI_COMM_WORLD_RANK:-0}" = 0 ]; then exec "$0" "$@"; else exec "$0" "$@" >/dev/null; fi' \
        "$py" -m pytest --with-mpi -m mpi -q -p no:cacheprovider
}

for n in 2 3; do
    echo "== MPI tests on $n ranks"
    status=0
    mpi_tests "$n" || status=$?
    # A 3-rank run hung about once in three under load until PETSc's duplicate communicators were kept alive
    # (psph.solvers.petsc.petsc_comm; README "Known issues": too rare to prove gone). A hang is a failure:
    # the stage is not run again.
    if [ "$status" = 124 ]; then
        echo "== MPI tests on $n ranks timed out after 900 s (a hang: README, Known issues)"
    fi
    if [ "$status" != 0 ]; then
        exit "$status"
    fi
done
echo "== all tests passed"
