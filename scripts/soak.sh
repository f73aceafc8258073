#!/usr/bin/env bash
# Memory soak (issue 13 §3 "Load"): the load test of tests/load.rs (ten simulators free-running
# at 1 kHz in one session, every stream recorded) for MINUTES minutes, the recordings cut into
# 1-minute segments (each checked, then deleted). Every 10 s the RSS of every process of the run
# (the test's own process, the services process with the recorder, each simulator) goes into
# OUT/rss.csv; at the end it prints first / last / max RSS per process, and the load test's
# figures (gaps, late steps, rates) are in OUT/load.json and OUT/load.log.
#
# Usage: scripts/soak.sh [MINUTES (default 30)] [OUT (default /tmp/koopbridge-soak)]
# Run it at normal priority (a 1 kHz real-time load under `nice` measures the scheduler), and
# note the machine's load (`uptime`) next to its figures.
set -euo pipefail
cd "$(dirname "$0")/.."
MINUTES=${1:-30}
OUT=${2:-/tmp/koopbridge-soak}
PERIOD=${SOAK_SAMPLE_SECONDS:-10}
mkdir -p "$OUT"

# Build the load test (and the binary it starts) and find its executable.
BIN=$(cargo test --release --test load --no-run 2>&1 | tee "$OUT/build.log" |
  sed -n 's/.*Executable tests\/load.rs (\(.*\))$/\1/p' | tail -n 1)
if [ -z "$BIN" ] || [ ! -x "$BIN" ]; then
  echo "soak: could not build the load test (see $OUT/build.log)" >&2
  exit 1
fi

echo "soak: $MINUTES min, sampling RSS every $PERIOD s into $OUT/rss.csv; load at start: $(cut -d' ' -f1-3 /proc/loadavg)"
KB_LOAD_SECONDS=$((MINUTES * 60)) KB_LOAD_SEGMENT_SECONDS=60 KB_LOAD_REPORT="$OUT/load.json" \
  "$BIN" --ignored --exact ten_simulators_at_1khz_are_recorded_without_gaps --nocapture \
  >"$OUT/load.log" 2>&1 &
ROOT=$!

# The process and all its descendants, by process id.
tree() {
  local p=$1 c
  echo "$p"
  for c in $(pgrep -P "$p" || true); do tree "$c"; done
}

# A stable name for process $1: the test itself, the services, or the simulator's id.
name_of() {
  local pid=$1 args
  [ "$pid" = "$ROOT" ] && { echo load-test; return; }
  args=$(tr '\0' ' ' <"/proc/$pid/cmdline" 2>/dev/null || true)
  case "$args" in
    *" sim "*) echo "sim-$(sed -n 's/.* --id \([^ ]*\).*/\1/p' <<<"$args")" ;;
    *" serve "*) echo services ;;
    *) echo "other-$pid" ;;
  esac
}

echo "elapsed_s,pid,process,rss_kb" >"$OUT/rss.csv"
START=$(date +%s)
while kill -0 "$ROOT" 2>/dev/null; do
  NOW=$(( $(date +%s) - START ))
  for p in $(tree "$ROOT"); do
    RSS=$(awk '/^VmRSS:/ {print $2}' "/proc/$p/status" 2>/dev/null || true)
    [ -n "$RSS" ] && echo "$NOW,$p,$(name_of "$p"),$RSS" >>"$OUT/rss.csv"
  done
  sleep "$PERIOD"
done
RC=0
wait "$ROOT" || RC=$?

echo "soak: load test exited with $RC after $(( $(date +%s) - START )) s; load at end: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "RSS per process (kB): first sample, first sample after 2 min (warm), last, max:"
awk -F, 'NR > 1 {
    if (!($3 in first)) { first[$3] = $4; order[++n] = $3 }
    if ($1 >= 120 && !($3 in warm)) warm[$3] = $4
    last[$3] = $4; if ($4 > max[$3]) max[$3] = $4
  }
  END { printf "%-12s %10s %10s %10s %10s\n", "process", "first", "warm", "last", "max";
        for (i = 1; i <= n; i++) { p = order[i];
          printf "%-12s %10d %10s %10d %10d\n", p, first[p], (p in warm) ? warm[p] : "-", last[p], max[p] } }' \
  "$OUT/rss.csv"
tail -n 15 "$OUT/load.log"
exit "$RC"
