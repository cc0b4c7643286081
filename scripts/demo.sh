#!/usr/bin/env bash
# The demo: installs the dependencies (with matplotlib), builds the diffphd tool, runs
# scenes/demo.json (a three-segment cantilever, middle 10x stiffer, sagging under gravity) into
# out/demo (VTU+PVD and OBJ frames, stats.csv, summary.json) and draws out/demo/chart.png.
set -euo pipefail
cd "$(dirname "$0")/.."
# OpenBLAS threads spin against OpenMP on small machines (docs/linalg.md): one BLAS thread.
export OPENBLAS_NUM_THREADS=${OPENBLAS_NUM_THREADS:-1}
bash scripts/install-deps.sh --demo
bash scripts/build.sh -DDIFFPHD_BUILD_TESTS=OFF
out=${1:-out/demo}
"${DIFFPHD_BUILD_DIR:-build}"/examples/diffphd run scenes/demo.json --out "$out"
/usr/bin/python3 scripts/plot_demo.py "$out/stats.csv" "$out/chart.png" \
  "demo: three-segment cantilever (middle 10x stiffer) under gravity"
echo "demo: frames in $out/frames (open $out/frames/demo.pvd in ParaView), chart in $out/chart.png"
