#!/usr/bin/env bash
# The multi-simulator loop against the slowest simulator alone (BENCHMARKS.md "Multi-simulator loop"; docs/log/2026-12.md "Session 7",
# issue 14 §1): scenarios/multi-sim.toml with STEPS control steps per simulator, run with
# `--loop-baseline` by each koopbridge binary given (default target/release/koopbridge), the
# binaries alternating for ROUNDS rounds, one line per run. Needs the Python set-up
# (scripts/setup-python.sh) and a release build. Take it on a quiet machine.
#   scripts/measure-multisim.sh [STEPS [ROUNDS [BINARY...]]]
set -euo pipefail
cd "$(dirname "$0")/.."
steps=${1:-2000}
rounds=${2:-2}
shift $(( $# < 2 ? $# : 2 ))
bins=("$@")
[ ${#bins[@]} -gt 0 ] || bins=(target/release/koopbridge)
work=results/multisim-timing
mkdir -p "$work"
# The scenario beside the original (its relative paths are the repository's).
sc=scenarios/.multisim-timing.toml
trap 'rm -f "$sc"' EXIT
# At CI's smoke budget (the models of tests/multi_sim.rs; the default budget takes minutes), every
# simulator STEPS control steps.
sed -e "s/^steps = \(100\|200\|300\)$/steps = $steps/" \
    -e "s/^train_windows = 600$/train_windows = 60/; s/^val_windows = 60$/val_windows = 12/; s/^test_windows = 60$/test_windows = 12/" \
    -e "s/^config = { iterations = 3000, hidden = \[128, 128\], n_mult = 8, /config = { iterations = 200, hidden = [32, 32], n_mult = 2, batch = 32, /" \
    scenarios/multi-sim.toml > "$sc"
# The budget lines above must match the scenario's: say so rather than time the default budget.
grep -q "^train_windows = 60$" "$sc" && grep -q "^config = { iterations = 200, " "$sc" || {
  echo "measure-multisim: scenarios/multi-sim.toml's [collect]/[train] budget lines changed; update the sed lines above" >&2; exit 2; }
for r in $(seq 1 "$rounds"); do
  for i in "${!bins[@]}"; do
    out=$work/bin$i-round$r
    rm -rf "$out"
    "${bins[$i]}" run "$sc" --loop-baseline --out "$out" > "$out.log" 2>&1 || { tail -20 "$out.log"; exit 1; }
    python3 - "$out/report.json" "${bins[$i]}" "$r" <<'PY'
import json, sys
l = json.load(open(sys.argv[1]))["control_loop"]
print(f"{sys.argv[2]} round {sys.argv[3]}: loop {l['macro_steps_per_second']:.0f} macro steps/s; "
      f"alone {[round(a) for a in l['alone_steps_per_second']]} ({', '.join(l['sims'])}); "
      f"slowdown vs the slowest alone {l['slowdown_vs_slowest_alone']:.3f}; "
      f"solve round trip median us {[round(x) for x in l['solve_round_trip_median_us']]}")
PY
  done
done
