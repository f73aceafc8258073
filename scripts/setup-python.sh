#!/usr/bin/env bash
# Sets up koopbridge's Python side: the venv .venv at the repository root with the pinned
# requirements.txt, the project's FMUs (adapters/fmu/build/*.fmu), and the pyo3 module
# `koopbridge` built by maturin (release) and installed into the venv. Idempotent; fast when
# nothing changed. Uses $CARGO_TARGET_DIR when set, else the workspace's target/ (so the Rust
# dependencies built by `cargo build --release` are reused). PYTHON picks the interpreter.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
python=${PYTHON:-python3}

if [ ! -x .venv/bin/python ]; then
  echo "setup-python: creating .venv with $("$python" --version 2>&1)"
  "$python" -m venv .venv
fi
venv_py=$root/.venv/bin/python

# Requirements: reinstalled only when requirements.txt changed (its hash is kept in the venv).
stamp=.venv/.koopbridge-requirements.sha256
want=$(cat requirements.txt adapters/drake/requirements-nodeps.txt | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null || true)" != "$want" ]; then
  echo "setup-python: installing requirements.txt"
  "$venv_py" -m pip install --quiet --disable-pip-version-check -r requirements.txt
  "$venv_py" -m pip install --quiet --disable-pip-version-check --no-deps -r adapters/drake/requirements-nodeps.txt
  echo "$want" > "$stamp"
fi

echo "setup-python: building the FMUs"
PYTHON="$venv_py" adapters/fmu/build.sh

echo "setup-python: building and installing the koopbridge Python module (maturin, release)"
VIRTUAL_ENV=$root/.venv PATH="$root/.venv/bin:$PATH" \
  "$root/.venv/bin/maturin" develop --release --quiet -m adapters/python/Cargo.toml
"$venv_py" -c 'import koopbridge; print("setup-python: koopbridge", koopbridge.__version__, "ready in .venv")'
