#!/usr/bin/env bash
# Reproduces the Koopman-core acceptance runs of SPEC.md (issue #2): the damped pendulum with both
# pairings and all four regulariser combinations, the double pendulum, m = 1000 for both, and the
# damped pendulum's sample-size curve (m = 1000 … 140,000), each 60,000 iterations at seed 17382.
# Runs that already have a metrics.json are skipped, so the script can be stopped and started
# again; it ends with one table (markdown) of test prediction errors and the scaling-law fits
# (`koopbridge scaling`, written to MODELS/scaling/{scaling.json,scaling.png}).
#
#   scripts/reproduce-core.sh [JOBS]     (default 2 runs at a time, 1 thread each, at nice 19)
#
# Environment: KOOPBRIDGE (binary, default target/release/koopbridge built first), DATA (default
# data), MODELS (default models/core), ONLY (a regular expression: run only the matching names).
# One run takes ~15 min on one core of a 2-core Zen3 (the double pendulum longer).
set -euo pipefail
cd "$(dirname "$0")/.."
JOBS="${1:-2}"
DATA="${DATA:-data}"
MODELS="${MODELS:-models/core}"
if [ -z "${KOOPBRIDGE:-}" ]; then
  cargo build --release --bin koopbridge >&2
  KOOPBRIDGE="${CARGO_TARGET_DIR:-target}/release/koopbridge"
fi
export KOOPBRIDGE DATA MODELS

for spec in damped-pendulum:aligned damped-pendulum:reference double-pendulum:reference; do
  env="${spec%%:*}" pairing="${spec##*:}"
  [ -f "$DATA/$env-$pairing/test.npz" ] || "$KOOPBRIDGE" data gen --env "$env" --pairing "$pairing" --out "$DATA/$env-$pairing" >&2
done

# name  env  pairing  m  extra-flags   (ordered by what the acceptance criteria need first)
runs=(
  "damped-aligned-both     damped-pendulum aligned   140000"
  "damped-aligned-noctrl   damped-pendulum aligned   140000 --no-ctrl"
  "double-reference-both   double-pendulum reference 140000"
  "damped-reference-m1000  damped-pendulum reference 1000"
  "double-reference-m1000  double-pendulum reference 1000"
  "damped-reference-both   damped-pendulum reference 140000"
  "damped-reference-noctrl damped-pendulum reference 140000 --no-ctrl"
  "damped-reference-nocov  damped-pendulum reference 140000 --no-cov"
  "damped-reference-none   damped-pendulum reference 140000 --no-ctrl --no-cov"
  "damped-aligned-nocov    damped-pendulum aligned   140000 --no-cov"
  "damped-aligned-none     damped-pendulum aligned   140000 --no-ctrl --no-cov"
  "damped-reference-m16000 damped-pendulum reference 16000"
  "damped-reference-m4000  damped-pendulum reference 4000"
  "damped-reference-m64000 damped-pendulum reference 64000"
  "double-reference-m16000 double-pendulum reference 16000"
  "double-reference-m4000  double-pendulum reference 4000"
  "double-reference-m64000 double-pendulum reference 64000"
  "damped-reference-m1000-seed76849  damped-pendulum reference 1000 --seed 76849"
  "damped-reference-m4000-seed76849  damped-pendulum reference 4000 --seed 76849"
  "damped-reference-m16000-seed76849 damped-pendulum reference 16000 --seed 76849"
)
if [ -n "${ONLY:-}" ]; then
  selected=()
  for r in "${runs[@]}"; do [[ "${r%% *}" =~ $ONLY ]] && selected+=("$r"); done
  [ "${#selected[@]}" -gt 0 ] || { echo "ONLY=$ONLY matches no run" >&2; exit 2; }
  runs=("${selected[@]}")
fi

run_one() {
  read -r name env pairing m flags <<<"$1"
  out="$MODELS/$name"
  [ -f "$out/metrics.json" ] && { echo "skip $name (done)" >&2; return 0; }
  mkdir -p "$MODELS/logs"
  echo "start $name" >&2
  # shellcheck disable=SC2086
  nice -n 19 "$KOOPBRIDGE" train --data "$DATA/$env-$pairing" --out "$out" --train-samples "$m" \
    --threads 1 --json $flags >"$MODELS/logs/$name.log" 2>&1 || { echo "FAILED $name (see $MODELS/logs/$name.log)" >&2; return 1; }
  echo "done $name: $(tail -n 1 "$MODELS/logs/$name.log" | python3 -c 'import json,sys; print(json.load(sys.stdin)["test_prediction_error"])')" >&2
}
export -f run_one
printf '%s\n' "${runs[@]}" | xargs -P "$JOBS" -I{} bash -c 'run_one "$@"' _ {}

echo "| run | env | pairing | m | ctrl | cov | test prediction error | it/s |"
echo "|---|---|---|---|---|---|---|---|"
for r in "${runs[@]}"; do
  read -r name env pairing m _ <<<"$r"
  f="$MODELS/$name/metrics.json"
  [ -f "$f" ] || continue
  python3 - "$f" "$name" "$env" "$pairing" "$m" <<'PY'
import json, sys
f, name, env, pairing, m = sys.argv[1:]
j = json.load(open(f))
c = j.get("config", {})
print(f"| {name} | {env} | {pairing} | {m} | {c.get('ctrl')} | {c.get('cov')} | {j['test_prediction_error']:.5f} | {j['iterations_per_second']:.0f} |")
PY
done

# The sample-size curves (m) of every environment/setting with at least 3 runs.
"$KOOPBRIDGE" scaling "$MODELS" --out "$MODELS/scaling" || echo "(scaling fit failed; see above)" >&2
