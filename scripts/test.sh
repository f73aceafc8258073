#!/usr/bin/env bash
# Runs every check of koopbridge on a fresh machine: formatting, lints, Rust tests, Python tests.
# Installs what it needs (Rust crates through cargo, the Python venv, the pyo3 module, the FMUs).
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TERM_COLOR=never
echo "== cargo fmt --check"
cargo fmt --all -- --check
echo "== cargo clippy"
cargo clippy --release --workspace --all-targets -- -D warnings
if [ -x scripts/setup-python.sh ]; then
  echo "== python environment"
  scripts/setup-python.sh
fi
echo "== cargo test"
cargo test --release --workspace
if [ -d .venv ] && [ -d adapters/python/tests ]; then
  echo "== pytest"
  .venv/bin/python -m pytest -q adapters
fi
