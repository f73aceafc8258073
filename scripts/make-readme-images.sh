#!/usr/bin/env bash
# Remakes README's two images:
#  - docs/images/live-view.png: Rerun's web viewer on the main job (scenarios/damped-pendulum-fmu.toml),
#    a viewer attached with `koopbridge view --web`, the page shot in headless Chromium
#    (scripts/view-screenshot.py; scripts/setup-browser.sh installs Chromium);
#  - docs/images/go2-frame.png: a frame of `koopbridge run scenarios/go2-survival.toml --video 0`
#    (GO2_SCENARIO / GO2_OUT choose another file or output folder: a folder of an earlier run
#    reuses its data and models; from nothing the Go2 scenario takes ~25 min on 2 cores).
# Needs the release build and .venv (scripts/setup-python.sh). Usage: scripts/make-readme-images.sh [live|go2|all]
set -euo pipefail
cd "$(dirname "$0")/.."
what=${1:-all}
exe=target/release/koopbridge
py=.venv/bin/python
out=${OUT:-results/readme-images}
mkdir -p "$out" docs/images

if [ "$what" = live ] || [ "$what" = all ]; then
  session=readme$$
  port=$($py -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
  "$exe" view --session "$session" --listen "tcp/127.0.0.1:$port" --web > "$out/viewer.log" 2>&1 &
  viewer=$!
  trap 'kill $viewer 2> /dev/null || true' EXIT
  url=
  for _ in $(seq 300); do
    url=$(grep -o 'live at http://[^ ]*' "$out/viewer.log" | cut -d' ' -f3 || true)
    [ -n "$url" ] && break
    sleep 0.1
  done
  [ -n "$url" ] || { cat "$out/viewer.log"; exit 1; }
  "$exe" run scenarios/damped-pendulum-fmu.toml --session "$session" --connect "tcp/127.0.0.1:$port" --out "$out/main-job"
  $py scripts/view-screenshot.py "$url" --out "$out/live-view.png" --expect /control/pend --expect /train --size 1600x1000
  kill "$viewer" 2> /dev/null || true
  $py - "$out/live-view.png" docs/images/live-view.png << 'PY'
import sys
from PIL import Image
img = Image.open(sys.argv[1])
img.resize((1200, round(img.height * 1200 / img.width)), Image.LANCZOS).save(sys.argv[2], optimize=True)
print("wrote", sys.argv[2])
PY
fi

if [ "$what" = go2 ] || [ "$what" = all ]; then
  go2_out=${GO2_OUT:-results/go2-survival}
  "$exe" run "${GO2_SCENARIO:-scenarios/go2-survival.toml}" --out "$go2_out" --video 0
  # The recommended controller's loop of reference 0, 2 s in.
  $py - "$go2_out" docs/images/go2-frame.png << 'PY'
import json, sys
from pathlib import Path
import imageio.v3 as iio
from PIL import Image
report = json.loads((Path(sys.argv[1]) / "report.json").read_text())
videos = [v for v in report["videos"] if "error-state" in v and "-edmd" not in v] or report["videos"]
frames = iio.imread(videos[0])
Image.fromarray(frames[min(50, len(frames) - 1)]).save(sys.argv[2], optimize=True)
print("wrote", sys.argv[2], "from", videos[0])
PY
fi
