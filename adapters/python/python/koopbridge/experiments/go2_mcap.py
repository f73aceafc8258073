"""Writes one lockstep closed loop as an MCAP file in the recorder's layout (PROTOCOL.md §8,
``bridge/src/services/recording_mcap.rs``): JSON messages with a JSON schema on the channels
``/koopbridge/{sim}/state``, ``…/input`` and ``…/reference``, channel metadata ``env`` and
``dt``, log time = k · dt in ns; Foxglove opens it as it is. A lockstep adapter publishes no
stream for the recorder service to subscribe to, and the Python client publishes none, so the
experiment writes the file itself."""

from __future__ import annotations

import json
from collections.abc import Sequence

import numpy as np

from .dataset_npz import write_atomic

__all__ = ["write_mcap"]


def _schema(title: str, key: str, named: str, names: Sequence[str]) -> bytes:
    props = {n: {"type": "number"} for n in names}
    s = {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": {
            "seq": {"type": "integer", "description": "publication sequence number"},
            "k": {"type": "integer", "description": "step index"},
            "t": {"type": "number", "description": "simulation time, s"},
            key: {"type": "array", "items": {"type": "number"}, "minItems": len(names), "maxItems": len(names)},
            named: {"type": "object", "properties": props},
        },
        "required": ["seq", "k", "t", key, named],
    }
    return json.dumps(s).encode()


def _message(k: int, t: float, key: str, named: str, names: Sequence[str], v: np.ndarray) -> bytes:
    vals = [float(a) for a in v]
    return json.dumps({"seq": k, "k": k, "t": t, key: vals, named: dict(zip(names, vals, strict=True))}).encode()


def write_mcap(path: str, sim: str, env: str, dt: float, state_names: Sequence[str], input_names: Sequence[str],
               x: np.ndarray, u: np.ndarray, reference: np.ndarray | None = None) -> None:
    """Writes states ``x`` ``(n+1, nx)``, inputs ``u`` ``(n, nu)`` (``u[k]`` held over step k)
    and the reference rows (row k at step k, the last repeated) to ``path`` atomically;
    non-finite states are left out (with the input that led to them)."""
    from mcap.writer import CompressionType, Writer

    ok = [k for k in range(len(x)) if np.all(np.isfinite(x[k]))]

    def write(f: object) -> None:
        w = Writer(f, compression=CompressionType.NONE)  # type: ignore[arg-type]
        w.start(profile="", library="koopbridge go2_mcap")
        meta = {"env": env, "dt": repr(float(dt))}

        def channel(leaf: str, title: str, key: str, named: str, names: Sequence[str]) -> int:
            sid = w.register_schema(name=title, encoding="jsonschema", data=_schema(title, key, named, names))
            return w.register_channel(topic=f"/koopbridge/{sim}/{leaf}", message_encoding="json", schema_id=sid, metadata=meta)

        st = channel("state", "koopbridge.State", "x", "state", state_names)
        inp = channel("input", "koopbridge.Input", "u", "input", input_names)
        rf = channel("reference", "koopbridge.Reference", "x_ref", "reference", state_names) if reference is not None else None
        for n, k in enumerate(ok):
            t_ns = round(k * dt * 1e9)
            if k > 0:
                w.add_message(inp, log_time=round((k - 1) * dt * 1e9), publish_time=round((k - 1) * dt * 1e9), sequence=n,
                              data=_message(k - 1, (k - 1) * dt, "u", "input", input_names, u[k - 1]))
            w.add_message(st, log_time=t_ns, publish_time=t_ns, sequence=n, data=_message(k, k * dt, "x", "state", state_names, x[k]))
            if rf is not None and reference is not None:
                row = reference[min(k, len(reference) - 1)]
                w.add_message(rf, log_time=t_ns, publish_time=t_ns, sequence=n, data=_message(k, k * dt, "x_ref", "reference", state_names, row))
        w.finish()

    write_atomic(path, write)
