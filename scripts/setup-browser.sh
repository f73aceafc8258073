#!/usr/bin/env bash
# Installs Debian's Chromium for the live view's browser test (adapters/python/tests/
# test_view_browser.py, scripts/view-screenshot.py): `apt-get install chromium` when `chromium` is
# not on PATH (as root, or through sudo). Idempotent; about a minute the first time.
set -euo pipefail
if command -v chromium > /dev/null 2>&1; then
  exit 0
fi
as_root=()
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo > /dev/null 2>&1; then
    as_root=(sudo -n)
  else
    echo "setup-browser: chromium is missing and this user cannot install packages; install Debian's chromium package" >&2
    exit 1
  fi
fi
echo "setup-browser: installing Debian's chromium (apt-get)"
export DEBIAN_FRONTEND=noninteractive
"${as_root[@]}" apt-get update -qq
"${as_root[@]}" apt-get install -y -qq chromium > /dev/null
chromium --version
