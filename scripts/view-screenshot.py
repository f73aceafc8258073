#!/usr/bin/env python3
"""Opens Rerun's web viewer (a `koopbridge run --view web` address) in headless Chromium, waits
until the session's data is drawn, and saves a screenshot; prints what the page shows as JSON.

Used by the live-view test (adapters/python/tests/test_view_browser.py) and to remake README's
screenshot (scripts/make-readme-images.sh). Talks to Chromium over the DevTools protocol
(`websockets`, in the venv): `--screenshot` alone captures the page while the Wasm still loads.

    .venv/bin/python scripts/view-screenshot.py URL --out shot.png [--expect TEXT] [--wait 150]
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import io
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np
import websockets
from PIL import Image

# What makes Debian's Chromium draw WebGL/WebGPU without a GPU here (SwiftShader) and stay off
# the closed network (background services fail their look-ups at every start otherwise).
CHROMIUM_FLAGS = [
    "--headless=new",
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-quic",
]


def chromium() -> str:
    """The Chromium executable (``$CHROMIUM``, else ``chromium`` on PATH)."""
    exe = os.environ.get("CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if not exe:
        raise SystemExit("error: no chromium on PATH (scripts/setup-browser.sh installs Debian's package)")
    return exe


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_chromium(size: tuple[int, int]) -> tuple[subprocess.Popen[bytes], str, list[dict[str, Any]]]:
    """Starts headless Chromium with a fresh profile; its process, profile and page targets."""
    port = free_port()
    profile = tempfile.mkdtemp(prefix="kb-chromium-")
    cmd = [chromium(), *CHROMIUM_FLAGS, f"--remote-debugging-port={port}", f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}", "about:blank"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json") as r:
                targets = [t for t in json.load(r) if t.get("type") == "page"]
            if targets:
                return proc, profile, targets
        except OSError:
            pass
        time.sleep(0.3)
    proc.kill()
    raise SystemExit("error: Chromium's DevTools endpoint did not come up in 30 s")


class Page:
    """One page target over the DevTools protocol."""

    def __init__(self, ws: Any) -> None:
        self.ws, self.next_id = ws, 0

    async def call(self, method: str, **params: Any) -> dict[str, Any]:
        self.next_id += 1
        await self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            msg = json.loads(await self.ws.recv())
            if msg.get("id") == self.next_id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    async def evaluate(self, expr: str) -> Any:
        r = await self.call("Runtime.evaluate", expression=expr, returnByValue=True, awaitPromise=True)
        return r.get("result", {}).get("value")

    async def screenshot(self) -> Image.Image:
        r = await self.call("Page.captureScreenshot", format="png")
        return Image.open(io.BytesIO(base64.b64decode(r["data"]))).convert("RGB")


def drawn(img: Image.Image) -> dict[str, float]:
    """How much the screenshot shows: distinct colours and the share of pixels off the most
    common colour (a blank or loading page has a handful of colours, almost all one)."""
    a = np.asarray(img.resize((400, 250))).reshape(-1, 3)
    colours, counts = np.unique(a, axis=0, return_counts=True)
    return {"colours": len(colours), "off_background": float(1 - counts.max() / counts.sum())}


# The viewer's state as text: index.html keeps the app as window._handle once it has started, and
# its viewer_state() (bytes) names the recording, the timelines and every view's entity paths.
STATE_JS = """(() => {
  const h = window._handle;
  if (!h || !h.viewer_state) return null;
  return Array.from(h.viewer_state()).map(c => (c >= 32 && c < 127) ? String.fromCharCode(c) : ' ').join('');
})()"""


async def capture(url: str, out: Path, expect: list[str], wait_s: float, size: tuple[int, int]) -> dict[str, Any]:
    """Opens ``url``, waits until the viewer's state names every text of ``expect`` and draws
    more than a loading page, saves the screenshot to ``out``; what it saw."""
    proc, profile, targets = await asyncio.to_thread(start_chromium, size)
    try:
        async with websockets.connect(targets[0]["webSocketDebuggerUrl"], max_size=64 * 2**20) as ws:
            page = Page(ws)
            await page.call("Page.enable")
            await page.call("Page.navigate", url=url)
            t0, state, img = time.monotonic(), "", None
            while time.monotonic() - t0 < wait_s:
                await asyncio.sleep(3)
                state = await page.evaluate(STATE_JS) or ""
                if all(e in state for e in expect):
                    await asyncio.sleep(3)  # a few frames with the data
                    img = await page.screenshot()
                    if drawn(img)["colours"] > 50:
                        break
            img = img or await page.screenshot()
            out.parent.mkdir(parents=True, exist_ok=True)
            img.save(out)
            found = {e: e in state for e in expect}
            return {"url": url, "found": found, "seconds": round(time.monotonic() - t0, 1), **drawn(img), "screenshot": str(out), "state": state[:20000]}
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        shutil.rmtree(profile, ignore_errors=True)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("url", help="the web viewer's address (printed by koopbridge run --view web)")
    p.add_argument("--out", type=Path, required=True, help="the screenshot (.png)")
    p.add_argument("--expect", action="append", default=["/control/"], help="a text the viewer's state must name before the screenshot (repeatable; default: /control/)")
    p.add_argument("--wait", type=float, default=150.0, help="seconds to wait for the data to be drawn (default: %(default)s)")
    p.add_argument("--size", default="1600x1000", help="window size WxH (default: %(default)s)")
    a = p.parse_args()
    w, h = (int(v) for v in a.size.split("x"))
    print(json.dumps(asyncio.run(capture(a.url, a.out, a.expect, a.wait, (w, h)))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
