#!/usr/bin/env bash
# The test command: installs the dependencies, builds everything, runs the fast test suite with
# CTest, then the reliability stages (docs/reliability.md): a subset of the suite under
# AddressSanitizer + UndefinedBehaviorSanitizer (scripts/test-sanitize.sh --ci) and every
# libFuzzer harness for a short bounded time (scripts/fuzz.sh). The last line is the sanitized
# CTest run's summary. Slow tests: scripts/test-slow.sh.
#
#   bash scripts/test.sh            # everything CI runs
#   bash scripts/test.sh --quick    # the Release suite only
# Environment: DIFFPHD_FUZZ_SECONDS (per harness, default 20), DIFFPHD_BUILD_DIR, DIFFPHD_JOBS.
set -euo pipefail
cd "$(dirname "$0")/.."
quick=0
if [[ ${1:-} == --quick ]]; then quick=1; fi
# OpenBLAS threads spin against OpenMP on small machines (docs/linalg.md): one BLAS thread.
export OPENBLAS_NUM_THREADS=${OPENBLAS_NUM_THREADS:-1}
bash scripts/install-deps.sh
bash scripts/build.sh
(cd "${DIFFPHD_BUILD_DIR:-build}" && ctest --output-on-failure -j "${DIFFPHD_JOBS:-$(nproc)}")
((quick)) && exit 0
bash scripts/fuzz.sh "${DIFFPHD_FUZZ_SECONDS:-20}"
bash scripts/test-sanitize.sh --ci
