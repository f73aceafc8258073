#!/usr/bin/env bash
# Reproduces the closed-loop comparison of issue #3 (docs/log/2026-11.md, "Closed loop"): every
# controller (Koopman MPC with both solvers, the clamped closed form, LQR, random shooting on the
# NNDM and on the true system, zero input) on the SPEC tasks, with the models that exist, and one
# markdown table per run. Needs the models of scripts/reproduce-core.sh (damped pendulum, aligned
# pairing) — it fits the EDMD models and generates the aligned double-pendulum data itself.
#
#   scripts/reproduce-control.sh            (results under results/control-comparison/)
#
# Environment: KOOPBRIDGE (binary, default target/release/koopbridge built first), MODELS
# (default models/core), NNDM (an NNDM model directory for the damped pendulum, optional).
set -euo pipefail
cd "$(dirname "$0")/.."
MODELS="${MODELS:-models/core}"
OUT="${OUT:-results/control-comparison}"
if [ -z "${KOOPBRIDGE:-}" ]; then
  cargo build --release --bin koopbridge >&2
  KOOPBRIDGE="${CARGO_TARGET_DIR:-target}/release/koopbridge"
fi
kb() { "$KOOPBRIDGE" "$@"; }

for env in damped-pendulum double-pendulum; do
  [ -f "data/$env-aligned/test.npz" ] || kb data gen --env "$env" --pairing aligned --out "data/$env-aligned" >&2
  [ -f "models/edmd-$env-aligned/config.json" ] || kb train --model edmd --data "data/$env-aligned" --out "models/edmd-$env-aligned" >&2
done

table() { # metrics.json -> markdown rows
  python3 - "$1" <<'PY'
import json, sys
for m in json.load(open(sys.argv[1])):
    t = "never" if m.get("time_to_goal_s") is None else f"{m['time_to_goal_s']:.2f} s"
    print(f"| {m['controller']} | {m['final_error']:.4f} | {m['final_angle_error']:.4f} | {t} | "
          f"{m['tracking_rms']:.3f} | {m['solve_ms_median']:.3f} | {m['solve_ms_p99']:.3f} | {m['input_violations']} |")
PY
}
run() { # name, then control arguments
  local name="$1"; shift
  echo "### $name"
  echo
  echo '```'
  echo "koopbridge control $* --solver all --out $OUT/$name"
  kb control "$@" --solver all --out "$OUT/$name" 2>&1 >/dev/null | grep -E "^(target|control authority|warning)" || true
  echo '```'
  echo
  echo "| controller | final err | final angle err | time to goal | track RMS | med ms | p99 ms | violations |"
  echo "|---|---|---|---|---|---|---|---|"
  table "$OUT/$name/metrics.json"
  echo
}

nndm_flag=()
[ -n "${NNDM:-}" ] && nndm_flag=(--nndm "$NNDM")
koop="$MODELS/damped-aligned-both"
if [ -f "$koop/config.json" ]; then
  run damped-koopman-regulate --model "$koop" "${nndm_flag[@]}" --env damped-pendulum --task regulate
  run damped-koopman-regulate-h30-from-1 --model "$koop" --env damped-pendulum --task regulate --horizon 30 --x0=-1.0,0.1
  run damped-koopman-track --model "$koop" --env damped-pendulum --task track
fi
run damped-edmd-regulate --model models/edmd-damped-pendulum-aligned --env damped-pendulum --task regulate
run double-edmd-regulate --model models/edmd-double-pendulum-aligned --env double-pendulum --task regulate
run double-edmd-regulate-u20 --model models/edmd-double-pendulum-aligned --env double-pendulum --task regulate --u-bound 20
run double-edmd-track --model models/edmd-double-pendulum-aligned --env double-pendulum --task track
