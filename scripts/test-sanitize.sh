#!/usr/bin/env bash
# Builds the fast test suite with AddressSanitizer and UndefinedBehaviorSanitizer (GCC, -O1, Eigen's
# assertions on) into its own build folder and runs it; any report fails the run. docs/reliability.md
# gives what it found and how long it takes.
#
#   bash scripts/test-sanitize.sh                  # every tests/test_*.cpp executable
#   bash scripts/test-sanitize.sh test_io test_mesh  # only these executables
#   bash scripts/test-sanitize.sh --ci             # the subset CI runs (below)
#
# The whole suite takes hours of CPU to build instrumented (the solver, contact and adjoint
# tests are 10-25 min each on one core), too long for CI's 2 cores; CI runs the readers, the
# scene parser, the linear algebra and the solver's own tests (docs/reliability.md has the
# figures) and the whole suite is run by hand before a release.
#
# Environment: DIFFPHD_SANITIZE_BUILD_DIR (default build-sanitize), DIFFPHD_JOBS (default nproc),
# DIFFPHD_SANITIZE_TIMEOUT (CTest per-test timeout in seconds, default 1500), DIFFPHD_SANITIZE_OPT
# (optimisation level, default -O1; -O2 keeps the same sanitizers and Eigen assertions and ran
# test_solver_physics' cases 1.1-8.6x faster, the Armadillo case in 10 min: give it its own
# build folder, docs/reliability.md).
set -euo pipefail
cd "$(dirname "$0")/.."
ci_tests=(test_io test_mesh test_material test_small_matrix test_generators test_scene test_anderson
          test_pd_matrix test_pd_system test_factor test_inverse_factor test_optim test_solver)
# Under the sanitizers (-O1, Eigen's assertions on) one test case takes over 10 minutes: plain
# PD (no Anderson) up to 5000 iterations per step at contrast 100. --ci leaves it out.
exclude="^$"
if [[ ${1:-} == --ci ]]; then
  set -- "${ci_tests[@]}"
  exclude="Anderson \(m = 1\) needs fewer iterations than plain PD"
fi
build_dir=${DIFFPHD_SANITIZE_BUILD_DIR:-build-sanitize}
jobs=${DIFFPHD_JOBS:-$(nproc)}
export OPENBLAS_NUM_THREADS=${OPENBLAS_NUM_THREADS:-1}
opt=${DIFFPHD_SANITIZE_OPT:--O1}
[[ $opt =~ ^-O[0-3g]$ ]] || { echo "test-sanitize.sh: DIFFPHD_SANITIZE_OPT must be one of -O0..-O3, -Og; found '$opt'" >&2; exit 2; }
san_flags="$opt -g1 -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=all"

# The library is header-only: the tests are the instrumented code. CUDA, the CLI and the
# benchmarks are left out (their code paths are the library's, exercised by the tests).
cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Sanitize \
  -DCMAKE_CXX_FLAGS_SANITIZE="$san_flags" \
  -DCMAKE_EXE_LINKER_FLAGS_SANITIZE="-fsanitize=address,undefined" \
  -DDIFFPHD_BUILD_EXAMPLES=OFF -DDIFFPHD_BUILD_BENCH=OFF -DDIFFPHD_WITH_CUDA=OFF
if (($#)); then
  cmake --build "$build_dir" -j "$jobs" --target "$@"
  regex="^($(IFS='|'; echo "$*")):"
else
  cmake --build "$build_dir" -j "$jobs"
  regex="^test_"
fi

# Reports abort the test (halt_on_error); leaks in the uninstrumented OpenMP/OpenBLAS runtimes
# are suppressed by name in tests/sanitize/lsan.supp, nothing of ours.
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:halt_on_error=1:abort_on_error=0:strict_string_checks=1:detect_stack_use_after_return=1:check_initialization_order=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$PWD/tests/sanitize/lsan.supp:print_suppressions=0}
cd "$build_dir"
ctest --output-on-failure -j "$jobs" -R "$regex" -E "$exclude" --timeout "${DIFFPHD_SANITIZE_TIMEOUT:-1500}"
