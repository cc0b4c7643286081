#!/usr/bin/env bash
# The soak (not part of the default suite; about 5 minutes of one core once built, most of it
# ball_drop): 10^4 steps of the demo and of two contact scenes (ball_drop: bounces then rest;
# incline_block: sticking friction), and the adjoint gradient of a 1000-step demo rollout.
# Each run checks that no step fails or stops unconverged, that resident memory stays flat after
# the warm-up, that the energy of the undamped body never rises, and that the gradient is finite
# (bench/soak.cpp). One JSON line per run goes to OUT (default out/soak/); exit status 1 when any
# check fails. docs/reliability.md keeps the latest figures.
#
#   bash scripts/soak.sh [STEPS] [GRADIENT_STEPS]     (defaults 10000 and 1000)
set -euo pipefail
cd "$(dirname "$0")/.."
steps=${1:-10000}
gsteps=${2:-1000}
out=${DIFFPHD_SOAK_OUT:-out/soak}
export OPENBLAS_NUM_THREADS=${OPENBLAS_NUM_THREADS:-1}
bash scripts/build.sh >/dev/null
cmake --build "${DIFFPHD_BUILD_DIR:-build}" --target soak
soak="${DIFFPHD_BUILD_DIR:-build}/bench/soak"
mkdir -p "$out"
status=0
run() {
  local name=$1
  shift
  echo "== soak $*"
  if "$soak" "$@" > "$out/$name.json"; then echo "ok: $(cat "$out/$name.json")"; else
    echo "FAILED: $(cat "$out/$name.json")"
    status=1
  fi
}
run demo_forward forward scenes/demo.json --steps "$steps"
run ball_drop_forward forward scenes/ball_drop.json --steps "$steps"
run incline_block_forward forward scenes/incline_block.json --steps "$steps"
run demo_gradient gradient scenes/demo.json --steps "$gsteps"
exit $status
