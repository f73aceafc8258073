"""koopbridge.Client against the Rust services (`koopbridge serve mpc models`): fetching a model
from the model store, configuring the MPC service and solving through it."""

from __future__ import annotations

import numpy as np
import pytest

import koopbridge
from conftest import Child, free_endpoint, koopbridge_binary_or_skip


def archive(files: list[dict], body: bytes, name: str = "evil") -> bytes:
    """A model archive per PROTOCOL.md §6, written here from the document."""
    import json
    import struct

    header = json.dumps({"name": name, "config": {}, "files": files}).encode()
    return b"KBM1" + struct.pack("<I", len(header)) + header + body


@pytest.mark.parametrize(
    "blob, message",
    [
        (b"nope", "missing KBM1 magic"),
        (archive([{"name": "../escape", "size": 1}], b"x"), "unsafe file name"),
        (archive([{"name": "a", "size": 5}], b"xy"), "truncated body"),
        (archive([{"name": "a", "size": 1}], b"xy"), "trailing bytes"),
        (archive([], b"", name="../up"), "model name"),
    ],
)
def test_fetch_model_refuses_bad_archives_and_writes_nothing(tmp_path, session_id, blob, message):
    """A model store (plain Zenoh here) answering with a bad archive: the bridge's unpacker
    refuses it, nothing is written beside or outside the destination."""
    import zenoh

    ep = free_endpoint()
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", f'["{ep}"]')
    with zenoh.open(conf) as z:
        q = z.declare_queryable(f"koopbridge/{session_id}/models/evil", lambda query: query.reply(query.key_expr, blob))
        out = tmp_path / "out"
        out.mkdir()
        with koopbridge.Client(session=session_id, connect=[ep]) as c:
            import time

            t_end = time.monotonic() + 20
            while True:
                try:
                    c.fetch_model("evil", str(out / "model"), timeout=2)
                    raise AssertionError("a bad archive was accepted")
                except koopbridge.BridgeTimeout:
                    assert time.monotonic() < t_end
                except koopbridge.KoopbridgeError as e:
                    assert message in str(e), str(e)
                    break
        q.undeclare()
    assert list(out.iterdir()) == [] and sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_fetch_configure_and_solve_through_the_services(tmp_path, session_id):
    exe = koopbridge_binary_or_skip()
    store = tmp_path / "store"
    model = koopbridge.KoopmanModel.init(nx=2, nu=1, hidden=[32, 32], n_mult=4, seed=9)
    model.save(str(store / "pend"))
    ep = free_endpoint()
    cmd = [str(exe), "serve", "mpc", "models", "--session", session_id, "--id", "s0", "--store", str(store),
           "--state-dir", str(tmp_path / "state"), "--listen", ep]
    with Child(cmd, tmp_path / "serve.log") as child, koopbridge.Client(session=session_id, connect=[ep]) as c:
        import time

        t_end = time.monotonic() + 30
        while True:
            try:
                got = c.fetch_model("pend", str(tmp_path / "fetched"))
                break
            except koopbridge.BridgeTimeout:
                assert time.monotonic() < t_end, child.output()
        fetched = koopbridge.KoopmanModel.load(got)
        np.testing.assert_array_equal(fetched.A, model.A)
        np.testing.assert_array_equal(fetched.encode([0.3, -0.2]), model.encode([0.3, -0.2]))
        with pytest.raises(koopbridge.RemoteError) as e:
            c.fetch_model("absent", str(tmp_path / "absent"))
        assert e.value.code == "not_found"
        assert not (tmp_path / "absent").exists()
        # MpcConfig is checked by the bridge's own type before anything is sent.
        with pytest.raises(koopbridge.KoopbridgeError, match="MPC configuration: unknown field `horizn`"):
            c.configure_mpc("s0", "pend", horizn=10)
        # An offset-free correction: a bad one is refused here; a good one is accepted for this
        # linear model too (issue 31), and the configuration below replaces it.
        with pytest.raises(koopbridge.KoopbridgeError, match="offset_free"):
            c.configure_mpc("s0", "pend", horizon=10, offset_free={"mode": "sideways", "radius": 1.0, "gain": [0.5, 0.5]})
        reply = c.configure_mpc("s0", "pend", horizon=10, offset_free={"mode": "trajectory", "radius": 1.0, "gain": [0.5, 0.5]})
        assert (reply["nx"], reply["nu"]) == (2, 1)
        reply = c.configure_mpc("s0", "pend", horizon=10, u_min=[-8.0], u_max=[8.0])
        assert (reply["nx"], reply["nu"], reply["horizon"]) == (2, 1, 10)
        sol = c.solve("s0", [-2.5, 0.1], [0.0, 0.0], model="pend", nu=1)
        want = koopbridge.Mpc(model, horizon=10, u_min=[-8.0], u_max=[8.0]).solve([-2.5, 0.1], [0.0, 0.0])
        assert sol["u"].shape == (10, 1) and sol["status"] in ("solved", "inaccurate")
        np.testing.assert_allclose(sol["u"], want["u"], atol=1e-9)
        # Error-state MPC about a plan (feed-forward u_ff, planned state now r): with R = 0 it is
        # the plain MPC towards the model's own rollout of the plan, computed here in numpy.
        r_now, u_ff = np.array([-2.4, 0.2]), 0.5 * np.sin(np.arange(10.0))
        z, rollout = np.asarray(model.encode(r_now), float), []
        for u in u_ff:
            z = np.asarray(model.A) @ z + np.asarray(model.B)[:, 0] * u
            rollout.append(z[:2])
        sol = c.solve("s0", [-2.5, 0.1], r_now, model="pend", nu=1, feedforward=u_ff)
        want = koopbridge.Mpc(model, horizon=10, u_min=[-8.0], u_max=[8.0]).solve([-2.5, 0.1], np.array(rollout))
        np.testing.assert_allclose(sol["u"], want["u"], atol=1e-6)
        with pytest.raises(koopbridge.RemoteError) as e:
            c.solve("s0", [-2.5, 0.1], r_now, model="pend", feedforward=u_ff[:9])
        assert e.value.code == "bad_request" and "feed-forward" in str(e.value)
        with pytest.raises(koopbridge.RemoteError) as e:
            c.solve("s0", [1.0], [0.0, 0.0], model="pend")
        assert e.value.code in ("dimension", "bad_request")


def test_attach_detach_and_recording_from_the_python_client(tmp_path, session_id):
    """The Python Client drives the free-run control plane through bridge's own functions:
    attach (typed refusals), record a stream, detach with the MPC's statistics."""
    import time

    exe = koopbridge_binary_or_skip()
    store = tmp_path / "store"
    koopbridge.KoopmanModel.init(nx=2, nu=1, hidden=[32, 32], n_mult=4, seed=9).save(str(store / "pend"))
    ep = free_endpoint()
    serve = [str(exe), "serve", "mpc", "models", "recorder", "--session", session_id, "--id", "s0", "--store",
             str(store), "--state-dir", str(tmp_path / "state"), "--listen", ep]
    sim = [str(exe), "sim", "--env", "damped-pendulum", "--id", "fr", "--session", session_id, "--connect", ep,
           "--free-run", "--rate", "100", "--steps", "200", "--wait-subscriber", "30"]
    with Child(serve, tmp_path / "serve.log") as services, koopbridge.Client(session=session_id, connect=[ep]) as c:
        t_end = time.monotonic() + 30
        while True:
            try:
                c.configure_mpc("s0", "pend", horizon=10, u_min=[-8.0], u_max=[8.0])
                break
            except koopbridge.BridgeTimeout:
                assert time.monotonic() < t_end, services.output()
        with pytest.raises(koopbridge.RemoteError) as e:
            c.attach("s0", "nosuch", "pend", [0.0, 0.0], timeout=10)
        assert e.value.code == "not_found"
        with pytest.raises(koopbridge.RemoteError) as e:
            c.record_stop("s0", "fr", "never", timeout=10)
        assert e.value.code == "not_found"
        with Child(sim, tmp_path / "sim.log") as free:
            t_end = time.monotonic() + 30
            while True:
                try:
                    assert c.attach("s0", "fr", "pend", [0.0, 0.0], timeout=10) == "fr"
                    break
                except koopbridge.RemoteError as err:
                    assert err.code == "not_found" and time.monotonic() < t_end, free.output()
                    time.sleep(0.1)
            with pytest.raises(koopbridge.RemoteError) as e:
                c.attach("s0", "fr", "pend", [0.0, 0.0], timeout=10)
            assert e.value.code == "busy"
            c.record_start("s0", "fr", window_steps=10)
            free.p.wait(timeout=60)
        summary = c.record_stop("s0", "fr", "fr-run")
        stats = c.detach("s0", "fr")
    assert summary["name"] == "fr-run" and summary["states"] > 0 and summary["windows"] > 0, summary
    assert stats["states"] > 0 and stats["commands"] > 0 and stats["commands"] <= stats["states"], stats
    assert (tmp_path / "state" / "data" / "fr-run.npz").is_file()
