#!/usr/bin/env bash
# Runs the test cases tagged [.slow] (hidden from the default suite) in every test executable.
set -euo pipefail
cd "$(dirname "$0")/.."
# OpenBLAS threads spin against OpenMP on small machines (docs/linalg.md): one BLAS thread.
export OPENBLAS_NUM_THREADS=${OPENBLAS_NUM_THREADS:-1}
bash scripts/install-deps.sh
bash scripts/build.sh
status=0
for t in "${DIFFPHD_BUILD_DIR:-build}"/tests/test_*; do
  [[ -x "$t" ]] || continue
  if "$t" --list-test-names-only "[.slow]" | grep -q .; then
    echo "== $(basename "$t") [.slow]"
    "$t" "[.slow]" || status=1
  fi
done
exit $status
