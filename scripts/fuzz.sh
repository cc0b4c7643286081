#!/usr/bin/env bash
# Builds the libFuzzer harnesses of tests/fuzz (clang++-14, -fsanitize=fuzzer,address,undefined)
# in build-fuzz/ and runs each for SECONDS (default 60), one after the other, seeded from
# tests/data. Exits non-zero on any crash, hang (-timeout), leak, out-of-memory or sanitizer
# report, and prints the reproducer. See docs/reliability.md.
#
#   scripts/fuzz.sh [SECONDS] [HARNESS...]     e.g. scripts/fuzz.sh 30, scripts/fuzz.sh 600 fuzz_gmsh
#
# Environment: DIFFPHD_FUZZ_BUILD (build folder, default build-fuzz), DIFFPHD_FUZZ_JOBS (ninja -j,
# default 2), CXX_FUZZ (compiler, default clang++-14). The corpus grows in BUILD/corpus/HARNESS
# and is kept between runs; reproducers land in BUILD/artifacts/HARNESS.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
seconds=${1:-60}
shift $(( $# > 0 ? 1 : 0 ))
build=${DIFFPHD_FUZZ_BUILD:-$root/build-fuzz}
jobs=${DIFFPHD_FUZZ_JOBS:-2}
cxx=${CXX_FUZZ:-clang++-14}
all=(fuzz_tetgen_node fuzz_tetgen_ele fuzz_gmsh fuzz_off fuzz_obj fuzz_scene fuzz_simulate)
harnesses=("${@:-${all[@]}}")
[[ $seconds =~ ^[0-9]+$ ]] || { echo "fuzz.sh: SECONDS must be a number, got '$seconds'" >&2; exit 2; }

command -v "$cxx" >/dev/null || { echo "fuzz.sh: $cxx not found (scripts/install-deps.sh)" >&2; exit 2; }
start=$SECONDS
cmake -S "$root/tests/fuzz" -B "$build" -G Ninja -DCMAKE_CXX_COMPILER="$cxx" >/dev/null
ninja -C "$build" -j"$jobs" "${harnesses[@]}"
echo "fuzz.sh: built ${#harnesses[@]} harnesses in $((SECONDS - start)) s"

# Seeds: the files of tests/data (good and bad) each harness reads, plus tests/fuzz/seeds/NAME;
# tests/fuzz/NAME.dict is passed as a libFuzzer dictionary. NAME is the harness's name without
# "fuzz_", except that fuzz_simulate reads what fuzz_scene reads (scene files).
inputs() { [[ $1 == fuzz_simulate ]] && echo scene || echo "${1#fuzz_}"; }
seeds() {
  local d=$root/tests/data
  case $1 in
    fuzz_tetgen_node) ls "$d"/*.node "$d"/bad/*.node ;;
    fuzz_tetgen_ele) ls "$d"/*.ele "$d"/bad/*.ele ;;
    fuzz_gmsh) ls "$d"/*.msh "$d"/bad/*.msh ;;
    fuzz_off) ls "$d"/*.off "$d"/bad/*.off ;;
    fuzz_obj) ls "$d"/*.obj "$d"/bad/*.obj ;;
    fuzz_scene | fuzz_simulate) ls "$d"/scenes/*.json "$root"/scenes/*.json ;;
  esac 2>/dev/null || true
  ls "$root/tests/fuzz/seeds/$(inputs "$1")"/* 2>/dev/null || true
}

export TMPDIR=$build/tmp  # the harnesses' input files (and the folders of crashed runs)
mkdir -p "$TMPDIR"
failed=()
for h in "${harnesses[@]}"; do
  corpus=$build/corpus/$h artifacts=$build/artifacts/$h log=$build/logs/$h.log
  mkdir -p "$corpus" "$artifacts" "$(dirname "$log")"
  seeds "$h" | while read -r f; do cp -n "$f" "$corpus/" 2>/dev/null || true; done
  echo "fuzz.sh: $h for $seconds s (corpus $(ls "$corpus" | wc -l) files, log $log)"
  dict=$root/tests/fuzz/$(inputs "$h").dict opts=()
  [[ -f $dict ]] && opts+=(-dict="$dict")
  rc=0
  "$build/$h" -max_total_time="$seconds" -max_len=8192 -timeout=10 -rss_limit_mb=2048 \
    -print_final_stats=1 -artifact_prefix="$artifacts/" "${opts[@]}" "$corpus" >"$log" 2>&1 || rc=$?
  grep -E '^stat::number_of_executed_units|^stat::peak_rss_mb' "$log" | sed "s/^/  $h: /" || true
  if ((rc != 0)); then
    failed+=("$h")
    echo "fuzz.sh: $h FAILED (exit $rc); the end of $log:" >&2
    tail -n 40 "$log" >&2
    echo "fuzz.sh: reproducers in $artifacts (rerun: $build/$h FILE):" >&2
    ls -l "$artifacts" >&2
  fi
done
echo "fuzz.sh: done in $((SECONDS - start)) s"
if ((${#failed[@]})); then
  echo "fuzz.sh: FAILED: ${failed[*]}" >&2
  exit 1
fi
echo "fuzz.sh: no crash, hang or leak in ${harnesses[*]}"
