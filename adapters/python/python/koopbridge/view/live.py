"""Follows one session live: subscribes to its view keys and the trainer's progress, queues what
arrives (Zenoh's callbacks never wait on Rerun), and logs it from one thread until stopped."""

from __future__ import annotations

import json
import os
import queue
import socket
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import rerun as rr
import zenoh

from .blueprint import layout
from .logger import RunLogger, SimLayout
from .robots import robot_for

__all__ = ["Sinks", "follow", "free_port"]


def free_port() -> int:
    """A free TCP port on the loopback interface."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Sinks:
    """Where the recording goes: a file (written as ``FILE.part``, renamed when complete), Rerun's
    web viewer on local ports, or its desktop viewer."""

    def __init__(self, save: str | None, web: bool, native: bool, web_port: int | None) -> None:
        self.save = Path(save) if save else None
        self.part = self.save.with_name(self.save.name + ".part") if self.save else None
        self.web, self.native, self.web_port = web, native, web_port
        self.url: str | None = None

    def attach(self, rec: rr.RecordingStream) -> None:
        """Points ``rec`` at every sink; raises with Rerun's own message when one cannot start."""
        sinks: list[Any] = []
        if self.part is not None:
            self.part.parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(self.part)))
        if self.web:
            grpc = free_port()
            sinks.append(rr.GrpcServerSink("127.0.0.1", grpc))
            connect = f"rerun+http://127.0.0.1:{grpc}/proxy"
            port = self.web_port or free_port()
            rr.serve_web_viewer(web_port=port, open_browser=False, connect_to=connect)
            self.url = f"http://127.0.0.1:{port}/?url={connect}"
        if self.native:
            if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
                raise RuntimeError("the desktop viewer needs a display (DISPLAY or WAYLAND_DISPLAY is not set)")
            port = free_port()
            rr.spawn(port=port, connect=False)
            sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"))
        rec.set_sinks(*sinks)

    def close(self, rec: rr.RecordingStream) -> None:
        """Flushes ``rec`` and completes the file."""
        rec.flush()
        rec.disconnect()
        if self.part is not None and self.save is not None and self.part.exists():
            os.replace(self.part, self.save)


def open_session(connect: Sequence[str], listen: Sequence[str], mode: str, config: str | None) -> zenoh.Session:
    """A plain Zenoh session with koopbridge's defaults (no multicast scouting)."""
    conf = zenoh.Config.from_file(config) if config else zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    if not config:
        conf.insert_json5("scouting/multicast/enabled", "false")
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    return zenoh.open(conf)


def _get_json(s: zenoh.Session, key: str, timeout: float = 2.0) -> Any:
    """The JSON of the first good reply to a query on ``key``, or None."""
    try:
        for reply in s.get(key, timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
    except Exception:  # noqa: BLE001 - a viewer shows what it can
        return None
    return None


def follow(
    s: zenoh.Session,
    session: str,
    viewer_id: str,
    rec: rr.RecordingStream,
    stop: threading.Event,
    ready: Any = None,
    video: Any = None,
) -> RunLogger:
    """Shows session ``session`` in ``rec`` until ``stop`` is set, then drains what arrived.
    ``ready()`` is called once subscribed, before the liveliness token is declared (whoever waits
    for the token finds what ``ready`` wrote)."""
    root = f"koopbridge/{session}"
    inbox: queue.SimpleQueue[tuple[str, str, bytes]] = queue.SimpleQueue()

    def put(kind: str) -> Any:
        return lambda sample: inbox.put((kind, str(sample.key_expr), sample.payload.to_bytes()))

    subs = [
        s.declare_subscriber(f"{root}/view/events", put("event")),
        s.declare_subscriber(f"{root}/view/*/step", put("step")),
        s.declare_subscriber(f"{root}/trainer/*/jobs/*/progress", put("train")),
    ]

    def layout_of(sim: str, nx: int, nu: int) -> SimLayout:
        info = _get_json(s, f"{root}/sim/{sim}/info")
        if not isinstance(info, dict):
            return SimLayout.unnamed(nx, nu)
        return SimLayout.from_info(info, robot_for(info))

    log = RunLogger(rec, layout_of, layout, video)
    log.send_layout()
    models: dict[str, str | None] = {}
    t0 = time.monotonic()
    if ready is not None:
        ready()
    token = s.liveliness().declare_token(f"{root}/alive/viewer/{viewer_id}")
    while True:
        try:
            kind, key, payload = inbox.get(timeout=0.2)
        except queue.Empty:
            log.flush()
            if stop.is_set():
                break
            continue
        try:
            m = json.loads(payload)
        except ValueError:
            continue
        parts = key.split("/")
        if kind == "step":
            log.step(parts[3], m, time.monotonic() - t0)
        elif kind == "event":
            log.event(m, time.monotonic() - t0)
        else:
            trainer, job = parts[3], parts[5]
            if job not in models:
                rec_ = _get_json(s, f"{root}/trainer/{trainer}/jobs/{job}")
                models[job] = rec_.get("spec", {}).get("model") if isinstance(rec_, dict) else None
            log.train_progress(job, m, time.monotonic() - t0, models[job])
    token.undeclare()
    for sub in subs:
        sub.undeclare()
    return log
