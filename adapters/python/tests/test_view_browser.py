"""The live view as a person looks at it (issue 45): a viewer attached to a session with
`koopbridge view --web`, a small Gymnasium MuJoCo scenario run into that session, Rerun's web
viewer opened in headless Chromium (Debian's package, scripts/setup-browser.sh) until the page
names the session's entities; the screenshot must show more than a loading page."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
import uuid

import pytest

pytest.importorskip("rerun")
pytest.importorskip("gymnasium")

from conftest import ROOT, Child, free_endpoint, idp_scenario, koopbridge_binary_or_skip, scenario_env  # noqa: E402

SCENARIO = idp_scenario("view-browser", steps=150)


def chromium_or_skip() -> None:
    if shutil.which("chromium") or os.environ.get("CHROMIUM"):
        return
    if os.environ.get("CI"):
        pytest.fail("no chromium: scripts/setup-browser.sh (run by scripts/test.sh) installs Debian's package")
    pytest.skip("no chromium (scripts/setup-browser.sh installs it)")


def test_the_web_viewer_shows_the_session_in_headless_chromium(tmp_path):
    chromium_or_skip()
    exe = koopbridge_binary_or_skip()
    env = scenario_env(exe)
    session = "kbview" + uuid.uuid4().hex[:8]
    ep = free_endpoint()
    viewer = Child([str(exe), "view", "--session", session, "--listen", ep, "--web"], tmp_path / "viewer.log")
    with viewer:
        url = None
        for _ in range(300):
            m = re.search(r"live at (http://\S+)", viewer.output())
            if m:
                url = m.group(1)
                break
            assert viewer.p.poll() is None, viewer.output()
            time.sleep(0.1)
        assert url, viewer.output()
        sc = tmp_path / "view-browser.toml"
        sc.write_text(SCENARIO)
        run = subprocess.run(
            [str(exe), "run", str(sc), "--out", str(tmp_path / "out"), "--session", session, "--connect", ep],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert run.returncode == 0, run.stderr[-3000:]
        shot = tmp_path / "view.png"
        r = subprocess.run(
            [sys.executable, str(ROOT / "scripts" / "view-screenshot.py"), url, "--out", str(shot), "--wait", "240", "--expect", session]
            + ["--expect", "/control/cart/state", "--expect", "/robot/cart"],
            capture_output=True,
            text=True,
            timeout=400,
        )
        assert r.returncode == 0, r.stderr[-3000:]
        seen = json.loads(r.stdout)
        assert all(seen["found"].values()), (seen["found"], seen["state"][:2000])
        # A loading or blank page has a handful of colours, almost all one; plots, a 3D robot
        # and text have thousands.
        assert seen["colours"] > 200 and seen["off_background"] > 0.1, seen
        assert shot.stat().st_size > 20_000
