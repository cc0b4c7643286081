#!/usr/bin/env bash
# `diffphd optimize` killed mid-way and resumed with --resume ends equal to an uninterrupted run:
# the same evaluations (x, loss, gradient, bit for bit in the log's shortest round-trip decimals),
# the same result but for wall times. Usage: cli_optimize_resume.sh DIFFPHD TASK WORKDIR
#   1. an abrupt exit (--stop-after-evaluation, std::_Exit) after evaluation 4;
#   2. a log whose last line was cut short by the kill (dropped, then recomputed);
#   3. a real kill -9 while the optimisation runs (skipped, with a note, when it ends first);
#   4. the errors: no log, another task, a damaged line.
set -uo pipefail
exe=$1 task=$2 work=$3
rm -rf "$work" && mkdir -p "$work"
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }
name=$(basename "$task" .json)

# $2's log and result equal to $1's: every field but the wall times and the replay count.
compare() {
  python3 - "$1" "$2" "$name" <<'PY' || fail "$2 differs from $1"
import json, sys
ref, got, name = sys.argv[1:4]
def log(d):
    rows = [json.loads(l) for l in open(f"{d}/{name}.evaluations.jsonl")]
    for r in rows: r.pop("seconds")
    return rows
def result(d):
    r = json.load(open(f"{d}/{name}.json"))
    for k in ("seconds", "seconds_forward", "seconds_backward", "replayed_evaluations"): r.pop(k)
    for h in r["history"]: h.pop("seconds")
    return r
a, b = log(ref), log(got)
if a != b:
    print(f"log: {len(a)} vs {len(b)} lines; first difference at",
          next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b))))
    sys.exit(1)
if result(ref) != result(got):
    print("result json differs"); sys.exit(1)
PY
}

opt() { "$exe" optimize "$task" --quiet "$@" > "$work/out.txt" 2>&1; }

# ---- the uninterrupted run ------------------------------------------------------------------
opt --out "$work/A" || { cat "$work/out.txt"; fail "uninterrupted run"; }
n=$(wc -l < "$work/A/$name.evaluations.jsonl")
[ "$n" -ge 8 ] || fail "the uninterrupted run made $n evaluations; the test needs >= 8"

# ---- 1. abrupt exit after evaluation 4 ------------------------------------------------------
opt --out "$work/B" --stop-after-evaluation 4
rc=$?
[ $rc -eq 137 ] || fail "--stop-after-evaluation 4: status $rc, expected 137"
[ "$(wc -l < "$work/B/$name.evaluations.jsonl")" -eq 5 ] || fail "B: the log does not hold 5 lines"
[ -e "$work/B/$name.json" ] && fail "B: a result file after the kill"
"$exe" optimize "$task" --resume "$work/B" > "$work/out.txt" 2>&1 || { cat "$work/out.txt"; fail "--resume B"; }
grep -q "5 evaluation(s) recorded; replaying" "$work/out.txt" || fail "--resume B: $(cat "$work/out.txt")"
grep -q "evaluation 4:" "$work/out.txt" && fail "--resume B recomputed a recorded evaluation"
grep -q "evaluation 5:" "$work/out.txt" || fail "--resume B did not go on from evaluation 5"
compare "$work/A" "$work/B"
grep -q '"replayed_evaluations": 5' "$work/B/$name.json" || fail "B: replayed_evaluations is not 5"

# ---- 2. the last line cut short ------------------------------------------------------------
mkdir -p "$work/C"
head -n 6 "$work/A/$name.evaluations.jsonl" > "$work/C/$name.evaluations.jsonl"
head -c 40 < <(sed -n 7p "$work/A/$name.evaluations.jsonl") >> "$work/C/$name.evaluations.jsonl"
opt --resume "$work/C" --out "$work/C" || { cat "$work/out.txt"; fail "--resume C"; }
compare "$work/A" "$work/C"

# ---- 3. kill -9 -----------------------------------------------------------------------------
"$exe" optimize "$task" --quiet --out "$work/D" > /dev/null 2>&1 &
pid=$!
for _ in $(seq 1 400); do
  [ -s "$work/D/$name.evaluations.jsonl" ] && [ "$(wc -l < "$work/D/$name.evaluations.jsonl")" -ge 2 ] && break
  sleep 0.05
done
kill -9 $pid 2> /dev/null
wait $pid 2> /dev/null
if [ -e "$work/D/$name.json" ]; then
  echo "note: the optimisation ended before kill -9 landed; part 3 only re-checks the result"
else
  echo "killed after $(wc -l < "$work/D/$name.evaluations.jsonl") evaluation line(s)"
fi
opt --resume "$work/D" || { cat "$work/out.txt"; fail "--resume D"; }
compare "$work/A" "$work/D"

# ---- 4. errors -------------------------------------------------------------------------------
mkdir -p "$work/E"
opt --resume "$work/E"
grep -q "no evaluation log to resume from" "$work/out.txt" || fail "empty folder: $(cat "$work/out.txt")"
taskdir=$(cd "$(dirname "$task")" && pwd)
sed -e 's/"initial": 3e6/"initial": 2e6/' -e "s|\"\.\./scenes/|\"$taskdir/../scenes/|" "$task" > "$work/other.json"
"$exe" optimize "$work/other.json" --quiet --resume "$work/B" > "$work/out.txt" 2>&1 && fail "--resume with another task succeeded"
grep -q "the log belongs to another task" "$work/out.txt" || fail "another task: $(cat "$work/out.txt")"
mkdir -p "$work/F"
sed '3s/"loss"/"lost"/' "$work/A/$name.evaluations.jsonl" > "$work/F/$name.evaluations.jsonl"
opt --resume "$work/F" && fail "--resume with a damaged line succeeded"
grep -q "$name.evaluations.jsonl:3: not an evaluation" "$work/out.txt" || fail "damaged line: $(cat "$work/out.txt")"

[ $failures -eq 0 ] && echo "optimize resume: all checks passed"
exit $failures
