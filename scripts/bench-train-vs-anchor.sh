#!/usr/bin/env bash
# Training speed of koopbridge's Rust trainer against the PyTorch anchor (shared/anchors/
# torch_koopman.py), measured side by side in the same run, alternating (A B A B ...): n_mult 16,
# both regularisers, batch 64, 2 threads. The anchor runs from a scratch venv OUTSIDE the project.
#
#   scripts/bench-train-vs-anchor.sh [ITERS] [PAIRS]   (default 2000 iterations each, 1 pair)
#
# By default both train on the damped pendulum. With DATA=DIR (a koopbridge dataset, e.g. the Go2
# expert data) koopbridge trains on DIR's windows and the anchor on random windows of the same
# size (its --dims NX,NU): the speed at that size, not an accuracy comparison.
#
# Environment: ANCHOR (path of torch_koopman.py, default ../shared/anchors/torch_koopman.py),
# VENV (default /tmp/koopbridge-anchor-venv), KOOPBRIDGE (binary, default: cargo build --release),
# DATA (see above).
set -euo pipefail
cd "$(dirname "$0")/.."
ITERS="${1:-2000}"
PAIRS="${2:-1}"
ANCHOR="${ANCHOR:-../shared/anchors/torch_koopman.py}"
VENV="${VENV:-/tmp/koopbridge-anchor-venv}"
[ -f "$ANCHOR" ] || { echo "anchor not found: $ANCHOR (set ANCHOR=...)" >&2; exit 2; }
if [ ! -x "$VENV/bin/python" ] || ! "$VENV/bin/python" -c "import torch, scipy, numpy" 2>/dev/null; then
  echo "creating the anchor venv in $VENV (pip install torch scipy numpy)..." >&2
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q torch scipy numpy
fi
if [ -z "${KOOPBRIDGE:-}" ]; then
  cargo build --release --bin koopbridge >&2
  KOOPBRIDGE="${CARGO_TARGET_DIR:-target}/release/koopbridge"
fi
anchor_args=(--timing-only --iters "$ITERS" --threads 2)
ours_args=(bench train --iters "$ITERS" --threads 2 --json)
if [ -n "${DATA:-}" ]; then
  [ -f "$DATA/train.json" ] || { echo "DATA=$DATA has no train.json (a koopbridge dataset directory)" >&2; exit 2; }
  dims=$(python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(f\"{d['nx']},{d['nu']}\")" "$DATA/train.json")
  anchor_args+=(--dims "$dims")
  ours_args+=(--data "$DATA")
fi
echo "load before: $(cut -d' ' -f1-3 /proc/loadavg)" >&2
for pair in $(seq 1 "$PAIRS"); do
  anchor_out=$("$VENV/bin/python" "$ANCHOR" "${anchor_args[@]}" 2>&1 | tail -n 1)
  echo "anchor:     $anchor_out"
  ours_json=$("$KOOPBRIDGE" "${ours_args[@]}" | tail -n 1)
  echo "koopbridge: $ours_json"
  anchor_ips=$(echo "$anchor_out" | sed -n 's/.*-> \([0-9.]*\) it\/s.*/\1/p')
  ours_ips=$(echo "$ours_json" | python3 -c "import json,sys; print(json.load(sys.stdin)['iterations_per_second'])")
  python3 - "$pair" "$anchor_ips" "$ours_ips" <<'PY'
import sys
p, a, o = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
print(f"pair {p}: anchor {a:.1f} it/s, koopbridge {o:.1f} it/s, ratio {o / a:.2f}x")
PY
done
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)" >&2
