"""The Zenoh ``collect`` request served by Python adapters: the MuJoCo adapter (a child process)
answers blocks equal, bit for bit, to ``FrankaSimulator.collect`` in this process, the same bytes
twice, resumable by block, typed errors for bad requests while it keeps serving; the FMU
adapter serves it through the generic ``collect_windows``; a plain ``Adapter`` without
``collect`` is collected with its own ``reset``/``step``."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import koopbridge
from conftest import Child, free_endpoint, reset_state
from koopbridge import SimulatorAdapter
from koopbridge.collect import UniformPolicy, collect_windows
from koopbridge.testing import listening_client

SPEC = {"kind": "uniform", "low": -0.12, "high": 0.12}


def remote_code(fn) -> str:
    with pytest.raises(koopbridge.RemoteError) as e:
        fn()
    return e.value.code


def test_the_mujoco_adapter_serves_collect(tmp_path, session_id):
    pytest.importorskip("mujoco")
    from koopbridge.adapters.mujoco.sim import FrankaSimulator

    ep = free_endpoint()
    cmd = [sys.executable, "-m", "koopbridge.adapters.mujoco", "--session", session_id, "--id", "arm", "--listen", ep]
    here = FrankaSimulator()
    with Child(cmd, tmp_path / "adapter.log"), koopbridge.Client(session=session_id, connect=[ep]) as c:
        c.connect_sim("arm", timeout=60)
        x, u = c.collect("arm", seed=42, block=1, block_windows=6, steps=15, policy=SPEC)
        assert x.shape == (6, 16, 17) and u.shape == (6, 15, 7)
        ref = here.collect(UniformPolicy((-0.12,) * 7, (0.12,) * 7), 42, 6, 15, start=6)
        np.testing.assert_array_equal(x, ref.x)
        np.testing.assert_array_equal(u, ref.u)
        x2, u2 = c.collect("arm", seed=42, block=1, block_windows=6, steps=15, policy=SPEC)
        assert x2.tobytes() == x.tobytes() and u2.tobytes() == u.tobytes()
        # Block 0 then a short block 1 of the same collection: the windows it started with.
        x0, _ = c.collect("arm", seed=42, block=0, block_windows=6, steps=15, policy=SPEC)
        xs, _ = c.collect("arm", seed=42, block=1, block_windows=6, windows=2, steps=15, policy=SPEC)
        np.testing.assert_array_equal(xs, x[:2])
        assert not np.array_equal(x0, x)
        # Typed errors, and the adapter serves on.
        # An unknown policy kind is refused by the client before anything is sent (the adapter's
        # own answer to one, `bad_request`, is checked on raw JSON in tests/collect.rs).
        with pytest.raises(ValueError, match="sine"):
            c.collect("arm", 1, 0, 4, 15, policy={"kind": "sine"})
        assert remote_code(lambda: c.collect("arm", 1, 0, 4, 15, policy={"kind": "uniform", "low": [0.0] * 3})) == "dimension"
        assert remote_code(lambda: c.collect("arm", 1, 0, 4, 15, policy={"kind": "uniform", "low": 1, "high": 0})) == "bad_request"
        assert remote_code(lambda: c.collect("arm", 1, 0, 1_000_000, 15)) == "too_large"
        assert remote_code(lambda: c.collect("arm", 1, 0, 4, 0)) == "bad_request"
        # The planned policy is known on the wire, but the MuJoCo simulator plans nothing.
        assert remote_code(lambda: c.collect("arm", 1, 0, 4, 15, policy={"kind": "planned", "windows_per_plan": 2})) == "unsupported"
        x3, _ = c.collect("arm", seed=42, block=1, block_windows=6, steps=15, policy=SPEC)
        np.testing.assert_array_equal(x3, x)
        # Lockstep goes on after a reset.
        np.testing.assert_array_equal(c.reset("arm", seed=3), here.reset(seed=3))
        assert c.connect_sim("arm")["stats"]["collected_windows"] == 6 + 6 + 6 + 2 + 6


def test_the_fmu_adapter_serves_collect(damped_fmu, session_id, serve_in_thread):
    from koopbridge.adapters.fmu.sim import FmuSimulator

    def fmu():
        return FmuSimulator(str(damped_fmu), ["u"], ["theta", "omega"], dt=0.02, initial=["theta0", "omega0"], x0_low=[-1, -1], x0_high=[1, 1])

    local = fmu()
    ref = collect_windows(local, UniformPolicy((-8.0,), (8.0,)), seed=5, n_windows=3, T=10, start=3)
    local.close()
    client, ep = listening_client(session_id)
    served = SimulatorAdapter(fmu())
    with serve_in_thread(served, session=session_id, id="fmu", connect=[ep]) as s:
        with client as c:
            c.connect_sim("fmu", timeout=20)
            x, u = c.collect("fmu", seed=5, block=1, block_windows=3, steps=10, policy={"kind": "uniform", "low": -8, "high": 8})
            assert remote_code(lambda: c.collect("fmu", 5, 0, 3, 10, policy={"kind": "planned"})) == "unsupported"
    assert s.error is None
    np.testing.assert_array_equal(x, ref.x)
    np.testing.assert_array_equal(u, ref.u)


class Decay(koopbridge.Adapter):
    """x+ = 0.5 x + u, no collect of its own."""

    def info(self):
        return dict(env="decay", dt=0.1, state_names=["a", "b"], input_names=["u"], u_min=[-1.0], u_max=[1.0])

    def reset(self, seed=None, x0=None):
        self.x = reset_state(seed, x0)
        return self.x

    def step(self, u):
        self.x = 0.5 * self.x + u[0]
        return self.x


def test_a_plain_adapter_is_collected_with_its_reset_and_step(session_id, serve_in_thread):
    client, ep = listening_client(session_id)
    with serve_in_thread(Decay(), session=session_id, id="d", connect=[ep]) as s:
        with client as c:
            c.connect_sim("d", timeout=20)
            x, u = c.collect("d", seed=1, block=0, block_windows=5, steps=4)
            again, _ = c.collect("d", seed=1, block=0, block_windows=5, steps=4)
            assert remote_code(lambda: c.collect("d", 1, 0, 5, 4, policy={"kind": "planned"})) == "unsupported"
    assert s.error is None
    assert x.tobytes() == again.tobytes()
    assert np.all(np.abs(u) <= 1.0) and np.abs(u).max() > 0.1
    for i in range(5):
        for t in range(4):
            np.testing.assert_array_equal(x[i, t + 1], 0.5 * x[i, t] + u[i, t, 0])
    assert len({tuple(w) for w in x[:, 0]}) == 5, "every window starts from its own seed"
