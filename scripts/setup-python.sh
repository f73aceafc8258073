#!/usr/bin/env bash
# Sets up koopbridge's Python side: the venv .venv at the repository root with the pinned
# requirements.txt, the project's FMUs (adapters/fmu/build/*.fmu), and the pyo3 module
# `koopbridge` built by maturin (release) and installed into the venv, and the paper's experiments
# (experiments/, on the venv's path; not in the wheel). Idempotent; fast when
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
# Lines marked `# no-deps` (robosuite, a folder of model files here) are installed on their own
# with --no-deps, after the others.
stamp=.venv/.koopbridge-requirements.sha256
want=$(sha256sum requirements.txt | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null || true)" != "$want" ]; then
  echo "setup-python: installing requirements.txt"
  with_deps=$(mktemp)
  trap 'rm -f "$with_deps"' EXIT
  grep -v -- '# no-deps' requirements.txt > "$with_deps"
  "$venv_py" -m pip install --quiet --disable-pip-version-check -r "$with_deps"
  mapfile -t no_deps < <(grep -- '# no-deps' requirements.txt | sed 's/#.*//; s/[[:space:]]//g' | grep -v '^$')
  if [ "${#no_deps[@]}" -gt 0 ]; then
    "$venv_py" -m pip install --quiet --disable-pip-version-check --no-deps "${no_deps[@]}"
  fi
  echo "$want" > "$stamp"
fi

echo "setup-python: building the FMUs"
PYTHON="$venv_py" adapters/fmu/build.sh

echo "setup-python: building and installing the koopbridge Python module (maturin, release)"
VIRTUAL_ENV=$root/.venv PATH="$root/.venv/bin:$PATH" \
  "$root/.venv/bin/maturin" develop --release --quiet -m adapters/python/Cargo.toml

# The paper's experiments (experiments/koopbridge_experiments) are not in the wheel: the venv finds
# them through a path file, as an editable install would.
site=$("$venv_py" -c 'import sysconfig; print(sysconfig.get_path("purelib"))')
echo "$root/experiments" > "$site/koopbridge_experiments.pth"
"$venv_py" -c 'import koopbridge, koopbridge_experiments; print("setup-python: koopbridge", koopbridge.__version__, "and its experiments ready in .venv")'
