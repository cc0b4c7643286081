#!/usr/bin/env bash
# The test command: installs the dependencies, builds everything, and runs the fast test suite
# with CTest (the last line is CTest's summary). Slow tests: scripts/test-slow.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
# OpenBLAS threads spin against OpenMP on small machines (docs/linalg.md): one BLAS thread.
export OPENBLAS_NUM_THREADS=${OPENBLAS_NUM_THREADS:-1}
bash scripts/install-deps.sh
bash scripts/build.sh
cd "${DIFFPHD_BUILD_DIR:-build}"
ctest --output-on-failure -j "${DIFFPHD_JOBS:-$(nproc)}"
