#!/usr/bin/env bash
# Builds the project's own FMUs from C (damped pendulum FMI 2.0 CS, double pendulum FMI 3.0 CS, and
# the FMU adapter's test FMUs typed_fmi2 / typed_fmi3 with a variable of every numeric type) against the FMI headers that fmpy ships, into adapters/fmu/build/*.fmu (or $1).
# Usage: adapters/fmu/build.sh [OUT_DIR]   (PYTHON=path/to/python with fmpy installed; default .venv)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
out="${1:-$here/build}"
python="${PYTHON:-$root/.venv/bin/python}"
[ -x "$python" ] || python=python3
headers="$("$python" -c 'import fmpy, os; print(os.path.join(os.path.dirname(fmpy.__file__), "c-code"))')"
[ -f "$headers/fmi2Functions.h" ] || { echo "error: FMI headers not found in $headers (is fmpy installed?)" >&2; exit 1; }
mkdir -p "$out"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

# build NAME PLATFORM_DIR: compiles src/NAME.c and zips it with src/NAME.xml into $out/NAME.fmu.
build() {
  local name=$1 platform=$2
  mkdir -p "$work/$name/binaries/$platform"
  gcc -std=c99 -D_POSIX_C_SOURCE=200809L -O2 -Wall -Wextra -Werror -fPIC -shared \
    -I"$headers" -I"$here/src" -o "$work/$name/binaries/$platform/$name.so" "$here/src/$name.c" -lm
  cp "$here/src/$name.xml" "$work/$name/modelDescription.xml"
  # zip through Python (no zip binary needed); written to a temporary name, then renamed.
  "$python" - "$work/$name" "$out/$name.fmu" <<'PY'
import os, sys, zipfile
src, dst = sys.argv[1], sys.argv[2]
tmp = dst + ".tmp"
with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
    for base, _, files in sorted(os.walk(src)):
        for f in sorted(files):
            p = os.path.join(base, f)
            z.write(p, os.path.relpath(p, src))
os.replace(tmp, dst)
PY
  echo "built $out/$name.fmu"
}

build damped_pendulum linux64
build van_der_pol linux64  # Van der Pol oscillator, FMI 2.0 CS with no inputs (an autonomous system)
if [ -f "$here/src/double_pendulum.c" ]; then
  build double_pendulum x86_64-linux
fi
build typed_fmi2 linux64
build typed_fmi3 x86_64-linux
