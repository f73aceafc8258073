#!/usr/bin/env bash
# Runs the paper's polynomial case study (Supplementary "System Nonlinearity and Scaling Law",
# Table toy_alpha; issue 26 §2): for each n_poly, α_m over m = 1k…140k at n_mult 16 and α_n over
# n_mult 1…16 at m = 140k, through `koopbridge sweep` (local trainer services), then the fits of
# both families with `koopbridge scaling` (one curve per n_poly) into OUT/fits/{m,n}.
#
#   scripts/polynomial-case-study.sh              SPEC: 80,000 iterations, 3 seeds (≈ 11 core-hours)
#   ITERATIONS=30000 SEEDS=17382 TRAINERS=3 scripts/polynomial-case-study.sh    (what BENCHMARKS
#                                                  records: 8 min on a 16-core machine)
#
# Environment: KOOPBRIDGE (binary; default target/release/koopbridge, built first), OUT (default
# results/polynomial-case-study), NPOLY (default "3 5 10 20 50"), ITERATIONS (default 80000),
# SEEDS (comma-separated, default 17382,76849,20965), TRAINERS (trainer services per n_poly, one
# thread each; default 1 — the n_poly sweeps run side by side, so use cores / 5).
# Every sweep resumes: points with a result are skipped and an interrupted training continues
# from its checkpoint, so the script can be stopped and started again.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${OUT:-results/polynomial-case-study}"
NPOLY="${NPOLY:-3 5 10 20 50}"
ITERATIONS="${ITERATIONS:-80000}"
SEEDS="${SEEDS:-17382,76849,20965}"
TRAINERS="${TRAINERS:-1}"
if [ -z "${KOOPBRIDGE:-}" ]; then
  cargo build --release --bin koopbridge >&2
  KOOPBRIDGE="${CARGO_TARGET_DIR:-target}/release/koopbridge"
fi
mkdir -p "$OUT/logs"

for p in $NPOLY; do
  [ -f "$OUT/data/np$p/test.npz" ] || "$KOOPBRIDGE" data gen --env polynomial --n-poly "$p" \
    --out "$OUT/data/np$p" > "$OUT/logs/data-np$p.log"
done

# One n_poly: the m family, then the n_mult family into the same sweep folder (the shared point
# m = 140k, n_mult 16 is trained once).
study() {
  local p="$1" common=(--data "$OUT/data/np$p" --seeds "$SEEDS" --iterations "$ITERATIONS"
    --local-trainers "$TRAINERS" --out "$OUT/sweep/np$p" --progress-every 60)
  "$KOOPBRIDGE" sweep "${common[@]}" --samples 1000,4000,16000,64000,140000 --n-mult 16 \
    > "$OUT/logs/sweep-m-np$p.log" 2>&1
  "$KOOPBRIDGE" sweep "${common[@]}" --samples 140000 --n-mult 1,2,4,8,16 \
    > "$OUT/logs/sweep-n-np$p.log" 2>&1
}
pids=()
for p in $NPOLY; do
  study "$p" &
  pids+=($!)
done
failed=0
for pid in "${pids[@]}"; do wait "$pid" || failed=1; done
[ "$failed" = 0 ] || echo "a sweep failed: see $OUT/logs/sweep-*.log (run again to resume)" >&2

"$KOOPBRIDGE" scaling --over m $(ls -d "$OUT"/sweep/np*/runs/*-n16-*) --out "$OUT/fits/m"
"$KOOPBRIDGE" scaling --over n $(ls -d "$OUT"/sweep/np*/runs/*-m140000-*) --out "$OUT/fits/n"
exit "$failed"
