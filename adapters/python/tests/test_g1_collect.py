"""The G1's collect policies: expert and expert+noise deterministic by seed and resumable at any
window, the G1's own command box by default, the recorded inputs the targets applied, expert and
uniform windows through a real Zenoh collect request, and the second shipped policy (ppo)."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("onnxruntime")

import koopbridge  # noqa: E402
from koopbridge import SimulatorAdapter  # noqa: E402
from koopbridge.adapters.legged.g1 import model as g  # noqa: E402
from koopbridge.adapters.legged.g1.sim import G1Simulator  # noqa: E402
from koopbridge.adapters.legged.policy import next_phase  # noqa: E402
from koopbridge.collect import UniformPolicy  # noqa: E402
from koopbridge.testing import listening_client  # noqa: E402

try:
    g.model_file(), g.policy_file()
except g.ModelError as e:  # pragma: no cover - pinned in requirements.txt
    pytest.skip(str(e), allow_module_level=True)

SHORT = {"kind": "expert", "windows_per_episode": 4, "warmup": 0.2}


@pytest.fixture(scope="module")
def sim() -> G1Simulator:
    return G1Simulator()


def test_expert_is_deterministic_by_seed_and_resumes_mid_episode(sim):
    adapter = SimulatorAdapter(sim)
    a = adapter.collect(SHORT, 5, 10, 8)
    b = adapter.collect(SHORT, 5, 10, 8)
    assert np.array_equal(a.x, b.x) and np.array_equal(a.u, b.u) and np.array_equal(a.reset_seeds, b.reset_seeds)
    assert a.x.shape == (10, 9, 53) and a.u.shape == (10, 8, 23)
    assert not np.array_equal(adapter.collect(SHORT, 6, 10, 8).x[:, 0], a.x[:, 0])
    part = adapter.collect(SHORT, 5, 6, 8, start=3)
    assert np.array_equal(part.x, a.x[3:9]) and np.array_equal(part.u, a.u[3:9])
    assert np.array_equal(a.x[0, -1], a.x[1, 0]) and a.reset_seeds[4] != a.reset_seeds[3]
    with pytest.raises(koopbridge.InvalidInput, match="not reset yet"):
        sim.step(g.default_pose()[sim.inputs])


def test_the_g1_command_box_is_the_policys_trained_range(sim):
    policy = sim.expert_policy({"kind": "expert"})
    ranges = sim.g1.meta.command_ranges
    assert list(policy.command_low) == [ranges["lin_vel_x"][0], ranges["lin_vel_y"][0], ranges["ang_vel_yaw"][0]]
    assert list(policy.command_high) == [ranges["lin_vel_x"][1], ranges["lin_vel_y"][1], ranges["ang_vel_yaw"][1]]
    # Given fields win over the G1's defaults.
    assert sim.expert_policy({"kind": "expert", "command_high": [0.5, 0, 0]}).command_high == (0.5, 0.0, 0.0)


def test_expert_noise_records_the_targets_applied(sim):
    clean = sim.collect(sim.expert_policy(SHORT), 9, 4, 10)
    noisy = sim.collect(sim.expert_policy({**SHORT, "kind": "expert+noise", "noise": 0.3}), 9, 4, 10)
    assert clean.reset_seeds[0] == noisy.reset_seeds[0] and not np.array_equal(clean.u, noisy.u)
    lo, hi = np.array(sim.info().u_min), np.array(sim.info().u_max)
    assert np.all((noisy.u >= lo) & (noisy.u <= hi)) and (np.any(noisy.u == hi) or np.any(noisy.u == lo))
    for i in (1, 3):
        np.testing.assert_array_equal(sim.reset(x0=noisy.x[i, 0]), noisy.x[i, 0])
        np.testing.assert_array_equal(np.array([sim.step(u) for u in noisy.u[i]]), noisy.x[i, 1:])


def test_expert_and_uniform_through_a_zenoh_collect_request(sim, session_id, serve_in_thread):
    client, ep = listening_client(session_id)
    with serve_in_thread(SimulatorAdapter(sim), session=session_id, id="g1", connect=[ep]) as served:
        with client as c:
            c.connect_sim("g1", timeout=20)
            xe, ue = c.collect("g1", seed=4, block=1, block_windows=2, steps=5, policy=SHORT)
            ref = sim.collect(sim.expert_policy(SHORT), 4, 2, 5, start=2)
            assert np.array_equal(xe, ref.x) and np.array_equal(ue, ref.u)
            x, u = c.collect("g1", seed=4, block=0, block_windows=2, steps=3)
            here = sim.collect(UniformPolicy(), 4, 2, 3)
            assert np.array_equal(x, here.x) and np.array_equal(u, here.u)
    assert served.error is None


def test_the_gait_phase_rule():
    step = 2 * math.pi * 0.02
    phase, standing = next_phase(np.array([0.0, math.pi]), False, np.array([0.5, 0, 0]), step)
    np.testing.assert_allclose(phase, [step, step - math.pi], atol=1e-15)  # the right foot wraps from pi to -pi
    phase, standing = next_phase(phase, standing, np.zeros(3), step)
    assert standing and phase.tolist() == [math.pi, math.pi]
    phase, standing = next_phase(phase, standing, np.array([0.0, 0.0, 0.2]), step)
    assert not standing and phase.tolist() == [0.0, math.pi]
    # A full period returns to the start.
    p = np.array([0.0, math.pi])
    for _ in range(50):
        p, _ = next_phase(p, False, np.array([0.3, 0, 0]), step)
    np.testing.assert_allclose(np.cos(p), [1.0, -1.0], atol=1e-12)


def test_the_ppo_expert_walks_too():
    ppo = G1Simulator(policy_name="ppo")
    assert ppo.expert.path.endswith("ppo_g1_29dof.onnx")
    w = ppo.collect(ppo.expert_policy({"kind": "expert", "command_low": [0.5, 0, 0], "command_high": [0.5, 0, 0],
                                       "windows_per_episode": 20, "warmup": 0.0}), 1, 20, 25)
    assert ppo.falls == 0 and 0.3 < w.x[10:, :, 4].mean() < 0.5


def test_dataset_script_writes_the_trainers_layout(tmp_path):
    import json
    import zipfile

    from koopbridge_experiments import g1_data

    out = tmp_path / "g1"
    args = ["--out", str(out), "--windows", "18", "--train", "12", "--val", "3", "--steps", "4", "--windows-per-episode", "3", "--block", "6",
            "--held", "locked"]
    assert g1_data.main(args) == 0
    with zipfile.ZipFile(out / "train.npz") as z:
        assert sorted(z.namelist()) == ["meta.json", "u.npy", "x.npy"]
        meta = json.loads(z.read("meta.json"))
    assert (meta["n"], meta["steps"], meta["nx"], meta["nu"], meta["env"], meta["seed"]) == (12, 4, 53, 23, "unitree-g1-locked", 42)
    assert "holosoma" in meta["policy"] and meta["state_names"][-1] == "base_height"
    with np.load(out / "test.npz") as z:
        assert z["x"].shape == (3, 5, 53) and z["u"].shape == (3, 4, 23)
        # The same windows as the simulator's own collect (the script adds nothing).
        locked = G1Simulator(held="locked")
        ref = locked.collect(locked.expert_policy({"kind": "expert", "windows_per_episode": 3, "push": 0.0}), 42, 3, 4, start=15)
        np.testing.assert_array_equal(z["x"], ref.x)
    summary = json.loads((out / "collect.json").read_text())
    assert summary["collected"] == 18 and summary["policy"]["kind"] == "expert" and summary["options"] == {"held": "locked", "policy_name": "fastsac"}
    assert not any(p.name.startswith(".blocks") for p in out.iterdir())
    assert "'held': 'locked'" in meta["source"] or '"held": "locked"' in meta["source"]
    assert g1_data.main(["--out", str(tmp_path / "bad"), "--windows", "18", "--train", "13", "--val", "2", "--windows-per-episode", "3"]) == 2
