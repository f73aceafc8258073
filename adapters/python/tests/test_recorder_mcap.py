"""The recorder's MCAP file, read back with the ``mcap`` package: one JSON channel each for the
states, inputs and reference, each with a JSON schema its messages satisfy; the states and
inputs are the ones of the ``.npz`` windows recorded from the same stream, the reference the
rows given at ``record_start``."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

import koopbridge
from conftest import Child, free_endpoint, koopbridge_binary

mcap_reader = pytest.importorskip("mcap.reader")
jsonschema = pytest.importorskip("jsonschema")


def test_the_recording_opens_as_mcap(tmp_path, session_id):
    exe = koopbridge_binary()
    if exe is None:
        pytest.skip("the koopbridge binary is not built (cargo build --release)")
    ep = free_endpoint()
    state = tmp_path / "state"
    serve = [str(exe), "serve", "recorder", "--session", session_id, "--id", "r0", "--state-dir", str(state), "--listen", ep]
    sim = [str(exe), "sim", "--env", "damped-pendulum", "--id", "fr", "--session", session_id, "--connect", ep,
           "--free-run", "--rate", "200", "--steps", "1000000", "--wait-subscriber", "30"]
    reference = np.column_stack([0.01 * np.arange(50), np.zeros(50)])
    with Child(serve, tmp_path / "serve.log") as services, koopbridge.Client(session=session_id, connect=[ep]) as c:
        with Child(sim, tmp_path / "sim.log") as free:
            t_end = time.monotonic() + 60
            while True:
                try:
                    c.record_start("r0", "fr", window_steps=10, reference=reference)
                    break
                except (koopbridge.BridgeTimeout, koopbridge.RemoteError):
                    assert time.monotonic() < t_end, services.output()
                    time.sleep(0.2)
            # Stopped while the simulator still runs: the recorder asks its `info` at `stop`
            # when the simulator was not up yet at `start`.
            time.sleep(1.5)
            summary = c.record_stop("r0", "fr", "run")
            assert free.p.poll() is None, free.output()
    assert summary["mcap"] == "run.mcap" and summary["gaps"] == 0, summary

    with open(state / "data" / "run.mcap", "rb") as f:
        reader = mcap_reader.make_reader(f)
        s = reader.get_summary()
        topics = {ch.topic: ch for ch in s.channels.values()}
        assert set(topics) == {"/koopbridge/fr/state", "/koopbridge/fr/input", "/koopbridge/fr/reference"}
        schemas = {}
        for ch in topics.values():
            sc = s.schemas[ch.schema_id]
            assert ch.message_encoding == "json" and sc.encoding == "jsonschema"
            assert ch.metadata["env"] == "damped-pendulum"
            schemas[ch.topic] = json.loads(sc.data)
        msgs: dict[str, list[dict]] = {t: [] for t in topics}
        log_times: list[int] = []
        for _, channel, message in reader.iter_messages(log_time_order=False):
            m = json.loads(message.data)
            jsonschema.validate(m, schemas[channel.topic])
            msgs[channel.topic].append(m)
            if channel.topic.endswith("state"):
                log_times.append(message.log_time)

    states, inputs, refs = (msgs[f"/koopbridge/fr/{leaf}"] for leaf in ("state", "input", "reference"))
    assert len(states) == summary["states"] == len(refs) and len(inputs) == len(states) - 1
    assert [m["k"] for m in states] == list(range(len(states)))
    assert np.all(np.diff(log_times) == 20_000_000), "log time = seq * dt"
    assert set(states[0]["state"]) == {"theta", "theta_dot"}
    assert states[3]["state"]["theta"] == states[3]["x"][0]
    # The .npz windows from the same stream: window i holds states 10 i .. 10 i + 10.
    with np.load(state / "data" / "run.npz") as z:
        x, u = z["x"], z["u"]
    assert x.shape[0] == summary["windows"] > 0
    xs = np.array([m["x"] for m in states])
    us = {m["k"]: m["u"] for m in inputs}
    for i in range(x.shape[0]):
        np.testing.assert_array_equal(x[i], xs[10 * i : 10 * i + 11])
        np.testing.assert_array_equal(u[i], [us[k] for k in range(10 * i, 10 * i + 10)])
    for m in refs:
        np.testing.assert_array_equal(m["x_ref"], reference[min(m["k"], 49)])
