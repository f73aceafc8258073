"""In-process collection on the MuJoCo Panda (SPEC data: home + U(±0.2) starts, U(±0.12)
commands every step): deterministic by seed, resumable by block, equal to the lockstep path over
Zenoh window by window, saved atomically; policies from JSON."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mujoco")

import koopbridge  # noqa: E402
from koopbridge import InvalidInput, SimulatorAdapter  # noqa: E402
from koopbridge.adapters.mujoco.model import HOME  # noqa: E402
from koopbridge.adapters.mujoco.sim import FrankaSimulator  # noqa: E402
from koopbridge.collect import UniformPolicy, collect_windows, policy_from_json  # noqa: E402
from koopbridge.testing import listening_client  # noqa: E402

SPEC_POLICY = UniformPolicy(low=(-0.12,) * 7, high=(0.12,) * 7)


@pytest.fixture(scope="module")
def sim():
    return FrankaSimulator()


def test_deterministic_resumable_and_specs_ranges(sim):
    w = sim.collect(SPEC_POLICY, seed=42, n_windows=12, T=15)
    assert w.x.shape == (12, 16, 17) and w.u.shape == (12, 15, 7)
    again = sim.collect(SPEC_POLICY, seed=42, n_windows=12, T=15)
    assert np.array_equal(w.x, again.x) and np.array_equal(w.u, again.u)
    block = sim.collect(SPEC_POLICY, seed=42, n_windows=4, T=15, start=8)
    assert np.array_equal(block.x, w.x[8:]) and np.array_equal(block.u, w.u[8:]) and block.start == 8
    other = sim.collect(SPEC_POLICY, seed=43, n_windows=12, T=15)
    assert not np.allclose(other.x[:, 0], w.x[:, 0])
    assert np.all(np.abs(w.u) <= 0.12) and np.abs(w.u).max() > 0.11
    q0 = w.x[:, 0, 3:10]
    assert np.all(np.abs(q0 - np.array(HOME)) <= 0.2 + 1e-12) and np.all(w.x[:, 0, 10:] == 0)


def test_collected_windows_equal_the_lockstep_path(sim, session_id, serve_in_thread):
    w = sim.collect(SPEC_POLICY, seed=7, n_windows=3, T=15)
    served_sim = FrankaSimulator()
    client, ep = listening_client(session_id)
    with serve_in_thread(SimulatorAdapter(served_sim), session=session_id, id="arm", connect=[ep]) as served:
        with client as c:
            c.connect_sim("arm", timeout=20)
            for i in range(3):
                np.testing.assert_array_equal(c.reset("arm", seed=int(w.reset_seeds[i])), w.x[i, 0])
                for t in range(15):
                    np.testing.assert_array_equal(c.step("arm", w.u[i, t])[2], w.x[i, t + 1])
    assert served.error is None


def test_save_npz_is_the_recorders_layout(sim, tmp_path):
    w = sim.collect(SPEC_POLICY, seed=1, n_windows=2, T=5)
    path = tmp_path / "block.npz"
    w.save_npz(path)
    with np.load(path) as z:
        assert np.array_equal(z["x"], w.x) and np.array_equal(z["u"], w.u) and int(z["start"]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["block.npz"]


def test_policies_from_json_and_bad_requests(sim):
    p = policy_from_json({"kind": "uniform", "low": -0.12, "high": 0.12})
    assert np.array_equal(sim.collect(p, 3, 2, 4).u, sim.collect(SPEC_POLICY, 3, 2, 4).u)
    # Default bounds: the simulator's own (±0.3).
    assert np.abs(sim.collect(policy_from_json({"kind": "uniform"}), 3, 4, 15).u).max() > 0.2
    with pytest.raises(InvalidInput, match="only 'uniform' and 'planned' are known"):
        policy_from_json({"kind": "sine"})
    with pytest.raises(InvalidInput, match="unknown fields"):
        policy_from_json({"kind": "uniform", "amp": 1})
    with pytest.raises(InvalidInput, match="bounds of 2 and 2 values for 7 inputs"):
        sim.collect(UniformPolicy((0, 0), (1, 1)), 1, 1, 3)
    with pytest.raises(InvalidInput, match="T >= 1"):
        sim.collect(SPEC_POLICY, 1, 1, 0)


def test_generic_collection_through_any_simulator(damped_fmu):
    from koopbridge.adapters.fmu.sim import FmuSimulator

    fmu = FmuSimulator(str(damped_fmu), ["u"], ["theta", "omega"], dt=0.02, initial=["theta0", "omega0"], x0_low=[-1, -1], x0_high=[1, 1])
    try:
        w = collect_windows(fmu, UniformPolicy((-8.0,), (8.0,)), seed=5, n_windows=3, T=10)
        ref = koopbridge.ReferenceSystem("damped-pendulum")
        for i in range(3):
            for t in range(10):
                np.testing.assert_allclose(w.x[i, t + 1], ref.step(w.x[i, t], w.u[i, t]), atol=1e-7)
    finally:
        fmu.close()


def test_simulator_adapter_uses_the_simulators_own_collect(sim):
    ad = SimulatorAdapter(FrankaSimulator())
    w = ad.collect({"kind": "uniform", "low": -0.12, "high": 0.12}, seed=42, n_windows=3, T=15)
    ref = sim.collect(SPEC_POLICY, seed=42, n_windows=3, T=15)
    assert np.array_equal(w.x, ref.x) and np.array_equal(w.u, ref.u)


def test_fast_path_clamps_commands_exactly_like_step(sim):
    # Commands beyond ±0.3: collect leaves the clamping to MuJoCo's control range, step clips.
    w = sim.collect(UniformPolicy((-1.0,) * 7, (1.0,) * 7), seed=3, n_windows=2, T=10)
    assert np.abs(w.u).max() > 0.9
    for i in range(2):
        np.testing.assert_array_equal(sim.reset(seed=int(w.reset_seeds[i])), w.x[i, 0])
        for t in range(10):
            np.testing.assert_array_equal(sim.step(w.u[i, t]), w.x[i, t + 1])
