#!/usr/bin/env bash
# Fuzzes every queryable of a live koopbridge session (all services + a simulator, started
# here) with N mutated, truncated and oversized payloads from a plain eclipse-zenoh client, and
# prints a JSON report (replies ok / typed error / internal / untyped / missing, dead processes,
# resident memory before and after). Exit code 0 only with 0 dead, 0 missing and 0 untyped.
# Usage: scripts/fuzz-services.sh [N=20000] [SEED=1]. Needs `cargo build --release` and the venv
# of scripts/setup-python.sh (eclipse-zenoh).
set -euo pipefail
cd "$(dirname "$0")/.."
n=${1:-20000}
seed=${2:-1}
exe=${KOOPBRIDGE_BIN:-${CARGO_TARGET_DIR:-target}/release/koopbridge}
if [ ! -x "$exe" ]; then
  echo "fuzz-services: $exe not built (cargo build --release)" >&2
  exit 2
fi
# The harness starts its processes in a scratch folder: give it the binary's absolute path.
exe=$(realpath "$exe")
exec .venv/bin/python scripts/fuzz_services.py --exe "$exe" --queries "$n" --seed "$seed"
