#!/usr/bin/env bash
# Installs the system packages the live view's tests need: Debian's Chromium for the browser
# test (adapters/python/tests/test_view_browser.py, scripts/view-screenshot.py) and Mesa's EGL
# for MuJoCo's offscreen renderer without a GPU (`koopbridge run --video`): `apt-get install`
# of what is missing (as root, or through sudo). Idempotent; about a minute the first time.
set -euo pipefail
packages=(chromium libegl1 libgl1-mesa-dri)
missing=()
for p in "${packages[@]}"; do
  # "install ok installed" only: a removed package keeps its config files and `dpkg -s` succeeds.
  [ "$(dpkg-query -W -f='${Status}' "$p" 2> /dev/null)" = "install ok installed" ] || missing+=("$p")
done
if [ "${#missing[@]}" -eq 0 ]; then
  exit 0
fi
as_root=()
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo > /dev/null 2>&1; then
    as_root=(sudo -n)
  else
    echo "setup-browser: ${missing[*]} missing and this user cannot install packages; install them with apt-get" >&2
    exit 1
  fi
fi
echo "setup-browser: installing ${missing[*]} (apt-get)"
export DEBIAN_FRONTEND=noninteractive
"${as_root[@]}" apt-get update -qq
"${as_root[@]}" apt-get install -y -qq "${missing[@]}" > /dev/null
chromium --version
