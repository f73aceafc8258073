#!/usr/bin/env bash
# Issue 26 §4: the regulariser table (Koopman base, +cov, +ctrl, +both, EDMD, NNDM) on Franka data
# that cover the figure-8 (scenarios/franka-figure8.toml: windows from home + U(±0.5), inputs
# U(±1.0)), SPEC's figure-8 error through the bridge with Q = I and with the q̇ weight 0.01.
#
#   scripts/franka-regulariser-table.sh OUT [SEEDS] [ROWS]
#     SEEDS default "17382 17383 17384" (the four Koopman rows; edmd and nndm take the first)
#     ROWS  default "base both ctrl cov edmd nndm"
#
# Every run is `koopbridge run VARIANT --out OUT/work` (one work folder, so the collected data are
# collected once and reused, and a row's model trained for Q = I is reused for q̇ 0.01); its
# report.json, figure8.png and variant go to OUT/{row}-s{seed}-{q}/. Resumable: a run whose
# OUT/{row}-s{seed}-{q}/report.json exists is skipped. Runs at nice 19, one at a time. The
# scenario's default budget (3,000 training windows, 1,500 iterations), not SPEC's, unless
# WINDOWS (training windows; validation and test a tenth each) and/or ITERATIONS are set in the
# environment — use a fresh OUT per budget, e.g.
#   WINDOWS=20000 ITERATIONS=10000 scripts/franka-regulariser-table.sh /tmp/franka-reg-20k
# At the end: the table (python -m koopbridge_experiments.franka_regulariser table --runs OUT).
set -euo pipefail
OUT=${1:?usage: $0 OUT [SEEDS] [ROWS]}
SEEDS=${2:-"17382 17383 17384"}
ROWS=${3:-"base both ctrl cov edmd nndm"}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
PY="$ROOT/.venv/bin/python"
mkdir -p "$OUT/work" "$OUT/bin"
# A copy of the binary: others rebuilding target/ mid-table do not change the runs.
[[ -x $OUT/bin/koopbridge ]] || cp "$ROOT/target/release/koopbridge" "$OUT/bin/koopbridge"
KB="$OUT/bin/koopbridge"
export KOOPBRIDGE_PYTHON="$PY"
BUDGET=()
[[ -n ${WINDOWS:-} ]] && BUDGET+=(--windows "$WINDOWS")
[[ -n ${ITERATIONS:-} ]] && BUDGET+=(--iterations "$ITERATIONS")
first=${SEEDS%% *}
for seed in $SEEDS; do
  for row in $ROWS; do
    if [[ ($row == edmd || $row == nndm) && $seed != "$first" ]]; then continue; fi
    for q in spec qd001; do
      dest="$OUT/$row-s$seed-$q"
      if [[ -f $dest/report.json ]]; then echo "skip $dest (done)"; continue; fi
      mkdir -p "$dest"
      (cd "$ROOT" && "$PY" -m koopbridge_experiments.franka_regulariser variant \
        --row "$row" --seed "$seed" --q "$q" "${BUDGET[@]}" --out "$dest/scenario.toml")
      rm -f "$OUT/work/report.json" "$OUT/work/figure8.png"
      echo "== $(date -u +%H:%M:%S) $row seed $seed $q"
      if nice -n 19 "$KB" run "$dest/scenario.toml" --out "$OUT/work" >"$dest/run.log" 2>&1; then
        cp "$OUT/work/figure8.png" "$dest/" 2>/dev/null || true
        cp "$OUT/work/report.json" "$dest/report.json"
        echo "   $(date -u +%H:%M:%S) done: $("$PY" -c 'import json,sys; print(json.load(open(sys.argv[1]))["figure8"]["errors"]["koopman-mpc"])' "$dest/report.json")"
      else
        echo "   FAILED (see $dest/run.log)"; tail -5 "$dest/run.log"
      fi
    done
  done
done
(cd "$ROOT" && "$PY" -m koopbridge_experiments.franka_regulariser table --runs "$OUT" --json "$OUT/table.json")
