#!/usr/bin/env bash
# Set up if needed, then run the demo scene on 2 MPI ranks and say where the results are.
#   run_scripts/demo.sh [OUT_DIR]
set -euo pipefail
"$(dirname "${BASH_SOURCE[0]}")/setup.sh"
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$PSPH_ROOT"
out="${1:-$PSPH_ROOT/demo_out}"
mpiexec -n 2 --oversubscribe "$PSPH_ROOT/.venv/bin/psph" run cases/static_perturbed.toml --out "$out" --overwrite \
    --set shifting.method=iips --set iips.max_newton=8
echo "demo: open $out/psph.xdmf in ParaView (Xdmf Reader); diagnostics in $out/history.csv and $out/summary.json"
