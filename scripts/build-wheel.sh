#!/usr/bin/env bash
# Builds the koopbridge Python SDK as an abi3 wheel (one wheel for every CPython >= 3.11) with the
# venv's maturin (scripts/setup-python.sh makes .venv) into target/wheels/, and prints its path.
# Uses $CARGO_TARGET_DIR when set, else the workspace's target/, so the release artifacts of
# `cargo build --release` are reused; numpy's wheel goes to target/wheels/deps. Usage: scripts/build-wheel.sh [extra maturin build args]
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
maturin=$root/.venv/bin/maturin
if [ ! -x "$maturin" ]; then
  echo "build-wheel: $maturin not found; run scripts/setup-python.sh first" >&2
  exit 2
fi
out=${CARGO_TARGET_DIR:-$root/target}/wheels
mkdir -p "$out"
# A stamp file marks the start: the wheel built now is the newest one newer than it.
stamp=$(mktemp)
trap 'rm -f "$stamp"' EXIT
VIRTUAL_ENV=$root/.venv PATH="$root/.venv/bin:$PATH" \
  "$maturin" build --release --quiet -m adapters/python/Cargo.toml \
  --interpreter "$root/.venv/bin/python" --out "$out" "$@" >&2
wheel=$(find "$out" -maxdepth 1 -name 'koopbridge-*-abi3-*.whl' -newer "$stamp" | sort | tail -n 1)
if [ -z "$wheel" ]; then
  echo "build-wheel: maturin finished but no abi3 wheel appeared in $out" >&2
  exit 1
fi
# The runtime dependencies (numpy, at the version the dev venv holds) as wheels in $out/deps, so
# that the wheel installs with `pip install --no-index --find-links $out --find-links $out/deps`:
# from pip's find-links (/opt/wheels) or its cache when they have it, else from the index.
deps=$out/deps
mkdir -p "$deps"
numpy=$("$root/.venv/bin/python" -c 'import numpy; print(numpy.__version__)')
if ! ls "$deps"/numpy-"$numpy"-*.whl >/dev/null 2>&1; then
  "$root/.venv/bin/python" -m pip download --quiet --no-deps --only-binary=:all: --no-index \
    -d "$deps" "numpy==$numpy" 2>/dev/null ||
    "$root/.venv/bin/python" -m pip download --quiet --no-deps --only-binary=:all: \
      -d "$deps" "numpy==$numpy" >&2
fi
echo "$wheel"
