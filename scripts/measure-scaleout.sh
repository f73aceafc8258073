#!/usr/bin/env bash
# Scale-out collection rate (BENCHMARKS.md "Bridge and collection › Scale-out"): one collect-only
# damped-pendulum scenario (3,000 windows x 15 steps) run embedded, as peers behind a
# `koopbridge router`, and in client mode through it, in one run, three rounds. Needs
# `cargo build --release`; KOOPBRIDGE=path overrides the binary. Take it on a quiet machine.
set -euo pipefail
cd "$(dirname "$0")/.."
B=$(realpath "${KOOPBRIDGE:-target/release/koopbridge}")
work=results/scaleout
rm -rf "$work" && mkdir -p "$work" && cd "$work"
cat > so.toml <<'TOML'
name = "scaleout"
[[sims]]
id = "pend"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform" }
train_windows = 3000
val_windows = 0
test_windows = 0
TOML
"$B" router --listen tcp/127.0.0.1:17447 > router.log 2>&1 &
router=$!
trap 'kill $router 2>/dev/null || true' EXIT
sleep 1
rate() { python3 -c "import json,sys;print(round(json.load(open(sys.argv[1]+'/report.json'))['collect']['macro_steps_per_second']))" "$1"; }
for r in 1 2 3; do
  "$B" run so.toml --out "emb$r" > /dev/null 2>&1
  "$B" run so.toml --out "peer$r" --connect tcp/127.0.0.1:17447 > /dev/null 2>&1
  "$B" run so.toml --out "client$r" --connect tcp/127.0.0.1:17447 --mode client > /dev/null 2>&1
  echo "round $r: embedded $(rate "emb$r")  peers-behind-router $(rate "peer$r")  client $(rate "client$r") macro steps/s"
done
