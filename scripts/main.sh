#!/usr/bin/env bash
# The main job: sets up the Python side (venv, FMUs, pyo3 module), builds koopbridge and runs the
# default scenario end to end on the embedded Zenoh default (peer mode on loopback, nothing to
# start by hand): the damped-pendulum FMU through the Python FMU adapter → lockstep collection →
# Koopman training in the trainer service → MPC regulation through the MPC service → report under
# results/. KOOPBRIDGE_SCENARIO picks another scenario; extra arguments go to `koopbridge run`
# (e.g. --full for the SPEC budget).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup-python.sh
cargo build --release --bin koopbridge
scenario=${KOOPBRIDGE_SCENARIO:-scenarios/damped-pendulum-fmu.toml}
exec "${CARGO_TARGET_DIR:-target}/release/koopbridge" run "$scenario" "$@"
