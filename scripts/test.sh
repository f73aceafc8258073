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
echo "== module import circles (koopman/, bridge/, the CLI)"
python3 scripts/check-module-cycles.py koopman/src bridge/src src
echo "== module import circles (the Python package and the paper's experiments)"
python3 scripts/check-python-cycles.py adapters/python/python/koopbridge experiments/koopbridge_experiments
if [ -x scripts/setup-python.sh ]; then
  echo "== python environment"
  scripts/setup-python.sh
fi
if [ -x .venv/bin/ruff ]; then
  echo "== ruff (adapters/python, config in adapters/python/pyproject.toml; experiments/ruff.toml)"
  .venv/bin/ruff check adapters/python
  .venv/bin/ruff check experiments
  echo "== stubtest (_native.pyi against the built module)"
  .venv/bin/python -m mypy.stubtest koopbridge._native
fi
echo "== cargo test"
cargo test --release --workspace
if [ -d .venv ] && [ -d adapters/python/tests ]; then
  echo "== browser for the live view's test (Debian's chromium)"
  scripts/setup-browser.sh
  echo "== pytest"
  .venv/bin/python -m pytest -q adapters
fi
if [ -d .venv ] && [ -x scripts/fuzz-services.sh ]; then
  echo "== fuzz-services (20,000 mutated payloads to a live session)"
  scripts/fuzz-services.sh 20000
fi
