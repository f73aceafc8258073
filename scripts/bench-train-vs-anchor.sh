#!/usr/bin/env bash
# Training speed of koopbridge's Rust trainer against the PyTorch anchor (shared/anchors/
# torch_koopman.py), measured side by side in the same run: damped pendulum, n_mult 16, both
# regularisers, batch 64, 2 threads. The anchor runs from a scratch venv OUTSIDE the project.
#
#   scripts/bench-train-vs-anchor.sh [ITERS]      (default 2000 iterations each)
#
# Environment: ANCHOR (path of torch_koopman.py, default ../shared/anchors/torch_koopman.py),
# VENV (default /tmp/koopbridge-anchor-venv), KOOPBRIDGE (binary, default: cargo build --release).
set -euo pipefail
cd "$(dirname "$0")/.."
ITERS="${1:-2000}"
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
echo "load before: $(cut -d' ' -f1-3 /proc/loadavg)" >&2
anchor_out=$("$VENV/bin/python" "$ANCHOR" --timing-only --iters "$ITERS" --threads 2 2>&1 | tail -n 1)
echo "anchor:     $anchor_out"
ours_json=$("$KOOPBRIDGE" bench train --iters "$ITERS" --threads 2 --json | tail -n 1)
echo "koopbridge: $ours_json"
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)" >&2
anchor_ips=$(echo "$anchor_out" | sed -n 's/.*-> \([0-9.]*\) it\/s.*/\1/p')
ours_ips=$(echo "$ours_json" | python3 -c "import json,sys; print(json.load(sys.stdin)['iterations_per_second'])")
python3 - "$anchor_ips" "$ours_ips" <<'PY'
import sys
a, o = float(sys.argv[1]), float(sys.argv[2])
print(f"anchor {a:.1f} it/s, koopbridge {o:.1f} it/s, ratio {o / a:.2f}x")
PY
