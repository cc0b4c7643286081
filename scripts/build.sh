#!/usr/bin/env bash
# Configures and builds diffphd (Release, Ninja) into build/ (or $DIFFPHD_BUILD_DIR).
# Extra arguments are passed to CMake's configure step.
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir=${DIFFPHD_BUILD_DIR:-build}
jobs=${DIFFPHD_JOBS:-$(nproc)}
cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Release "$@"
cmake --build "$build_dir" -j "$jobs"
