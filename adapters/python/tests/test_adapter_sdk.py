"""koopbridge.Adapter served over Zenoh (bridge::adapter) and driven by koopbridge.Client
(bridge's Rust client): lockstep semantics, typed errors from Python exceptions, stopping."""

from __future__ import annotations

import struct
import threading
import time

import numpy as np
import pytest

import koopbridge
from conftest import reset_state
from koopbridge.testing import listening_client


class Linear(koopbridge.Adapter):
    """x⁺ = 0.5 x + u (nx = nu = 2); raises on demand to test error replies."""

    def __init__(self):
        self.x = np.zeros(2)
        self.calls = 0

    def info(self):
        return dict(env="linear", dt=0.1, state_names=["a", "b"], input_names=["p", "q"], u_min=[-1, -1], u_max=[1, 1], version="1")

    def reset(self, seed=None, x0=None):
        self.x = reset_state(seed, x0)
        return self.x

    def step(self, u):
        self.calls += 1
        assert isinstance(u, np.ndarray) and u.dtype == np.float64
        if u[0] == 0.25:
            raise ValueError("u[0] = 0.25 is cursed")
        if u[0] == -0.25:
            raise koopbridge.InvalidInput("negative quarter refused")
        self.x = 0.5 * self.x + u
        return self.x


def test_lockstep_steps_errors_and_stop(session_id, serve_in_thread):
    sim = Linear()
    client, ep = listening_client(session_id)  # multicast scouting is off: the adapter connects to the client
    with serve_in_thread(sim, session=session_id, id="lin", connect=[ep]) as served:
        with client as c:
            info = c.connect_sim("lin", timeout=10)
            assert info["env"] == "linear" and info["state_names"] == ["a", "b"] and info["kind"] == "python"
            assert info["dt"] == 0.1 and info["mode"] == "lockstep"
            x = c.reset("lin", x0=[1.0, -2.0])
            np.testing.assert_array_equal(x, [1.0, -2.0])
            k, t, x = c.step("lin", [0.1, 0.2])
            assert k == 1 and t == pytest.approx(0.1)
            np.testing.assert_allclose(x, [0.6, -0.8])
            # A Python exception becomes a sim_failure reply with the Python message...
            with pytest.raises(koopbridge.RemoteError, match="ValueError: u\\[0\\] = 0.25 is cursed") as e:
                c.step("lin", [0.25, 0.0])
            assert e.value.code == "sim_failure"
            # ...InvalidInput a bad_request reply...
            with pytest.raises(koopbridge.RemoteError) as e:
                c.step("lin", [-0.25, 0.0])
            assert e.value.code == "bad_request" and "negative quarter refused" in str(e.value)
            # ...and the adapter keeps serving from where it was.
            k, t, x = c.step("lin", [0.0, 0.0])
            assert k == 2
            np.testing.assert_allclose(x, [0.3, -0.4])
            # Bad requests are refused by the Rust side without calling Python.
            calls = sim.calls
            with pytest.raises(koopbridge.RemoteError) as e:
                c.step("lin", [0.1])
            assert e.value.code == "dimension" and sim.calls == calls
            x = c.reset("lin", seed=5)
            np.testing.assert_array_equal(x, np.random.default_rng(5).uniform(-1, 1, 2))
    assert served.error is None, served.error
    assert served.stats["steps"] == 2 and served.stats["resets"] == 2 and served.stats["errors"] >= 3


class Ending(Linear):
    """Linear with a step status: it clips u to ±1 (``clipped``), ``terminated`` while
    |a| > 1, ``truncated`` from its third step on; ``bad`` replaces the status when set."""

    def reset(self, seed=None, x0=None):
        self.k, self.bad = 0, None
        return super().reset(seed, x0)

    def step(self, u):
        self.clipped = bool(np.any(np.abs(u) > 1))
        self.k += 1
        return super().step(np.clip(u, -1, 1))

    def step_status(self):
        if self.bad is not None:
            return self.bad
        return {"terminated": bool(abs(self.x[0]) > 1), "truncated": self.k >= 3, "clipped": self.clipped}


def test_step_status_reaches_the_client_in_the_step_reply(session_id, serve_in_thread):
    sim = Ending()
    client, ep = listening_client(session_id)
    with serve_in_thread(sim, session=session_id, id="end", connect=[ep]) as served:
        with client as c:
            c.connect_sim("end", timeout=10)
            c.reset("end", x0=[0.0, 0.0])
            flags = lambda t, tr, cl: {"terminated": t, "truncated": tr, "clipped": cl}  # noqa: E731
            k, _, x, status = c.step("end", [0.5, 0.0], with_status=True)
            assert (k, status) == (1, flags(False, False, False))
            # u = 2 is clipped to 1: a = 0.25 + 1 = 1.25 > 1, terminated; the plain call still
            # returns (k, t, x).
            k, t, x = c.step("end", [2.0, 0.0])
            assert k == 2 and t == pytest.approx(0.2)
            np.testing.assert_allclose(x, [1.25, 0.0])
            k, _, x, status = c.step("end", [0.0, 0.0], with_status=True)
            assert (k, status) == (3, flags(False, True, False))
            # The retried step 1 comes from the adapter's cache with its status; on the wire it
            # is type 0x09 ending in the status byte terminated | clipped = 0x05, while step 0's
            # reply (no flag) is the plain type 0x02.
            assert c.step_at("end", 1, [2.0, 0.0], with_status=True)[3] == flags(True, False, True)
            key = "sim/end/step"
            raw = c.query(key, struct.pack("<2sBBQI2d", b"KB", 1, 1, 1, 2, 2.0, 0.0))
            assert raw[:4] == b"KB\x01\x09" and raw[-1] == 0x05 and len(raw) == 4 + 8 + 8 + 4 + 16 + 1
            raw = c.query(key, struct.pack("<2sBBQI2d", b"KB", 1, 1, 0, 2, 0.5, 0.0))
            assert raw[:4] == b"KB\x01\x02" and len(raw) == 4 + 8 + 8 + 4 + 16
            assert sim.k == 3, "cached replies did not step the simulator"
            # A status that is not None or a dict of the known flags: sim_failure, naming it;
            # the adapter keeps serving.
            for bad, text in [({"fallen": True}, "unknown key 'fallen'"), (3, "must return None or a dict")]:
                sim.bad = bad
                with pytest.raises(koopbridge.RemoteError) as e:
                    c.step("end", [0.0, 0.0])
                assert e.value.code == "sim_failure" and text in str(e.value), str(e.value)
            c.reset("end", x0=[0.0, 0.0])
            assert c.step("end", [0.0, 0.0], with_status=True)[3] == flags(False, False, False)
    assert served.error is None, served.error


def test_a_simulator_without_step_status_gives_empty_flags(session_id, serve_in_thread):
    client, ep = listening_client(session_id)
    with serve_in_thread(Linear(), session=session_id, id="lin", connect=[ep]):
        with client as c:
            c.connect_sim("lin", timeout=10)
            c.reset("lin", x0=[5.0, 5.0])
            _, _, _, status = c.step("lin", [1.0, 1.0], with_status=True)
            assert status == {"terminated": False, "truncated": False, "clipped": False}


def test_the_gil_is_released_while_serving(session_id, serve_in_thread):
    # A Python thread keeps running while serve() waits on Zenoh.
    sim = Linear()
    with serve_in_thread(sim, session=session_id, id="lin"):
        time.sleep(0.2)
        n = 0
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 0.3:
            n += 1
        assert n > 10000


def test_info_is_checked_before_serving(session_id):
    class Bad(Linear):
        def info(self):
            d = super().info()
            d["u_max"] = [1.0]
            return d

    with pytest.raises(ValueError, match="2 input names but 2 u_min and 1 u_max values"):
        Bad().serve(session=session_id, id="bad")

    class Missing(koopbridge.Adapter):
        pass

    with pytest.raises(NotImplementedError, match="must implement info"):
        Missing().serve(session=session_id, id="missing")


def test_free_run_publishes_and_stops_after_steps(session_id):
    sim = Linear()
    stats = sim.serve(session=session_id, id="fr", free_run=True, rate_hz=200.0, steps=20, x0=[1.0, 1.0])
    assert stats["steps"] == 20 and stats["published"] == 21
    np.testing.assert_allclose(sim.x, [0.5**20, 0.5**20])


def test_free_run_waits_for_a_state_subscriber_when_asked(session_id):
    """``wait_subscriber`` reaches bridge's adapter: with nobody subscribed, 20 steps at 200 Hz
    (0.1 s) start only after the wait; a bad value or use outside free-run is refused."""
    sim = Linear()
    t0 = time.perf_counter()
    stats = sim.serve(session=session_id, id="fw", free_run=True, rate_hz=200.0, steps=20, x0=[1.0, 1.0], wait_subscriber=1.0)
    assert stats["steps"] == 20
    assert time.perf_counter() - t0 >= 1.0
    with pytest.raises(ValueError, match="wait_subscriber"):
        sim.serve(session=session_id, id="fw", free_run=True, steps=2, wait_subscriber=-1.0)
    with pytest.raises(ValueError, match="free_run=True only"):
        sim.serve(session=session_id, id="fw", wait_subscriber=1.0)


def test_stop_from_another_thread_returns_promptly(session_id):
    sim = Linear()
    done = threading.Event()

    def run():
        sim.serve(session=session_id, id="st")
        done.set()

    th = threading.Thread(target=run, daemon=True)
    th.start()
    time.sleep(0.5)
    assert sim.serving
    t0 = time.perf_counter()
    sim.stop()
    assert done.wait(2.0)
    assert time.perf_counter() - t0 < 1.0
    assert not sim.serving
