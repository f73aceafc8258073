#!/usr/bin/env bash
# Reliability soak of the secure QUIC link (issue 29): the test of tests/quic_soak.rs for MINUTES
# minutes: `koopbridge router` on QUIC with mutual authentication and the access-control list of
# config/router-quic-acl.json5, the trainer and model store as one client, a damped pendulum as
# another, and the operator stepping it in lockstep at full speed while a trainer job after
# another runs and a 256x256 model is fetched from the store over and over. Prints (and writes
# to OUT/report.json) the steps, lost replies, failed transfers and jobs, and process deaths;
# exit code 0 only with none lost, none failed and none dead. CI runs the 20 s version as part
# of `cargo test` (KB_SOAK_SECONDS unset).
#
# Usage: scripts/soak-quic.sh [MINUTES (default 10)] [OUT (default /tmp/koopbridge-soak-quic)]
# It is a reliability figure, not a timing one: note the machine's load next to it.
set -euo pipefail
cd "$(dirname "$0")/.."
MINUTES=${1:-10}
OUT=${2:-/tmp/koopbridge-soak-quic}
mkdir -p "$OUT"
BIN=$(cargo test --release --test quic_soak --no-run 2>&1 | tee "$OUT/build.log" |
  sed -n 's/.*Executable tests\/quic_soak.rs (\(.*\))$/\1/p' | tail -n 1)
if [ -z "$BIN" ] || [ ! -x "$BIN" ]; then
  echo "soak-quic: could not build the soak test (see $OUT/build.log)" >&2
  exit 1
fi
echo "soak-quic: $MINUTES min; load at start: $(cut -d' ' -f1-3 /proc/loadavg)"
RC=0
KB_SOAK_SECONDS=$((MINUTES * 60)) KB_SOAK_REPORT="$OUT/report.json" \
  "$BIN" --exact quic_router_holds_lockstep_training_and_model_transfers --nocapture \
  >"$OUT/soak.log" 2>&1 || RC=$?
echo "soak-quic: exit code $RC; load at end: $(cut -d' ' -f1-3 /proc/loadavg)"
if [ -f "$OUT/report.json" ]; then cat "$OUT/report.json"; else tail -n 30 "$OUT/soak.log"; fi
exit "$RC"
