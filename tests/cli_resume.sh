#!/usr/bin/env bash
# `diffphd run` killed mid-way and resumed ends byte-for-byte equal to an uninterrupted run
# (frames, PVD, OBJ; stats.csv but for its wall-time column), and --resume says what is wrong
# when it cannot continue. Usage: cli_resume.sh DIFFPHD SCENE OTHER_SCENE WORKDIR
#   1. an abrupt exit (--stop-after-frame, std::_Exit) after frame 6 of 12, checkpoints every 4;
#   2. a real kill -9 once the first checkpoint exists, on a longer run (skipped, with a note,
#      when the run finishes before the signal lands);
#   3. the errors: no checkpoint, another scene, another option, a complete run.
set -uo pipefail
exe=$1 scene=$2 other=$3 work=$4
rm -rf "$work" && mkdir -p "$work"
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }

# Every frame file of $1 equal to $2's, the same file set, stats.csv equal but for "seconds".
compare() {
  local ref=$1 got=$2
  (cd "$ref/frames" && ls) > "$work/ref.list"
  (cd "$got/frames" && ls) > "$work/got.list"
  cmp -s "$work/ref.list" "$work/got.list" || fail "$got/frames: other files than $ref/frames"
  for f in "$ref"/frames/*; do
    cmp -s "$f" "$got/frames/$(basename "$f")" || fail "$got/frames/$(basename "$f") differs"
  done
  cmp -s <(cut -d, -f1-9,11- "$ref/stats.csv") <(cut -d, -f1-9,11- "$got/stats.csv") ||
    fail "$got/stats.csv differs (wall-time column aside)"
  grep -q '"complete": true' "$got/summary.json" || fail "$got/summary.json not complete"
  local a b
  a=$(grep '"steps"' "$ref/summary.json") b=$(grep '"steps"' "$got/summary.json")
  [ "$a" = "$b" ] || fail "$got/summary.json: $b, uninterrupted $a"
}

# What a kill leaves must be readable: whole stats lines, complete frame files, summary.
readable() {
  local d=$1 n
  n=$(head -1 "$d/stats.csv" | tr -cd , | wc -c)
  awk -F, -v n="$n" 'NF - 1 != n { bad = 1 } END { exit bad }' "$d/stats.csv" ||
    fail "$d/stats.csv has a partial line"
  for f in "$d"/frames/*.vtu "$d"/frames/*.pvd; do
    [ "$(tail -c 11 "$f")" = "</VTKFile>" ] || fail "$f is cut short"
  done
  grep -q '"complete": false' "$d/summary.json" || fail "$d/summary.json: not a run in progress"
}

run() { "$exe" run "$@" > "$work/out.txt" 2>&1; }

# ---- 1. abrupt exit after frame 6 -----------------------------------------------------------
run "$scene" --frames 12 --checkpoint-every 4 --out "$work/A" || fail "uninterrupted run"
run "$scene" --frames 12 --checkpoint-every 4 --out "$work/B" --stop-after-frame 6
rc=$?
[ $rc -eq 137 ] || fail "--stop-after-frame 6: status $rc, expected 137"
readable "$work/B"
grep -q '"frames_done": 6' "$work/B/summary.json" || fail "B/summary.json: frames_done is not 6"
[ "$(cut -d, -f1 "$work/B/stats.csv" | tail -1)" = 6 ] || fail "B/stats.csv does not end at frame 6"
run "$scene" --resume "$work/B" || { cat "$work/out.txt"; fail "--resume B"; }
grep -q "resumed from the checkpoint of frame 4" "$work/out.txt" || fail "--resume B: $(cat "$work/out.txt")"
compare "$work/A" "$work/B"
ls "$work"/B/*.tmp "$work"/B/frames/*.tmp > /dev/null 2>&1 && fail "temporary files left in B"

# ---- 2. kill -9 ---------------------------------------------------------------------------
frames=60
run "$scene" --frames $frames --checkpoint-every 2 --out "$work/C" || fail "uninterrupted run C"
"$exe" run "$scene" --frames $frames --checkpoint-every 2 --out "$work/D" > /dev/null 2>&1 &
pid=$!
for _ in $(seq 1 2000); do
  [ -e "$work/D/checkpoint.bin" ] && break
  sleep 0.005
done
sleep 0.05
if kill -9 $pid 2> /dev/null; then
  wait $pid 2> /dev/null
  done_frames=$(grep -o '"frames_done": [0-9]*' "$work/D/summary.json" | grep -o '[0-9]*$')
  if grep -q '"complete": true' "$work/D/summary.json"; then
    echo "NOTE: the run finished before kill -9 landed; only the abrupt exit was tested"
  else
    echo "kill -9 landed after frame $done_frames of $frames"
    readable "$work/D"
    run "$scene" --resume "$work/D" || { cat "$work/out.txt"; fail "--resume D"; }
    compare "$work/C" "$work/D"
  fi
else
  wait $pid
  echo "NOTE: the run finished before kill -9 landed; only the abrupt exit was tested"
fi

# ---- 3. errors ------------------------------------------------------------------------------
expect_error() {  # pattern, then the arguments of diffphd run
  local pattern=$1
  shift
  run "$@"
  local rc=$?
  [ $rc -eq 2 ] || fail "run $*: status $rc, expected 2"
  grep -Eq "$pattern" "$work/out.txt" || fail "run $*: '$(cat "$work/out.txt")' lacks '$pattern'"
}
mkdir -p "$work/empty"
expect_error "error: --resume .*empty: no checkpoint.bin" "$scene" --resume "$work/empty"
expect_error "error: --resume .*: no such folder" "$scene" --resume "$work/missing"
run "$scene" --frames 12 --checkpoint-every 4 --out "$work/E" --stop-after-frame 5
expect_error "checkpoint belongs to another scene" "$other" --resume "$work/E"
expect_error "started with --eps-rel unset \(the scene's\), this command has 0.001" \
  "$scene" --resume "$work/E" --eps-rel 1e-3
expect_error "the run is complete \(frame 12 of 12\); pass a larger --frames" "$scene" --resume "$work/A"
expect_error "names another" "$scene" --resume "$work/A" --out "$work/B"

# A complete run extended: 12 frames, then --resume --frames 16, equals a 16-frame run.
run "$scene" --frames 16 --checkpoint-every 4 --out "$work/F" || fail "run F"
run "$scene" --resume "$work/A" --frames 16 || { cat "$work/out.txt"; fail "--resume A --frames 16"; }
compare "$work/F" "$work/A"

if [ $failures -gt 0 ]; then
  echo "$failures failure(s)"
  exit 1
fi
echo "resume: all checks passed"
