#!/usr/bin/env bash
# The main job: builds koopbridge and runs the default scenario end to end on the embedded Zenoh
# default (peer mode on loopback, nothing to start by hand). Extra arguments go to `koopbridge run`.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --bin koopbridge
scenario=${KOOPBRIDGE_SCENARIO:-scenarios/damped-pendulum.toml}
exec target/release/koopbridge run "$scenario" "$@"
