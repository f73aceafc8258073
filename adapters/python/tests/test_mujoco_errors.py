"""Bad input to the MuJoCo adapter gets a typed error and the adapter keeps serving: wrong-length
and NaN commands, a reset outside the joint limits, an unstable step (NaN in MuJoCo's state →
sim_failure, then a fresh reset works), and missing or malformed model files named clearly."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("mujoco")

import koopbridge  # noqa: E402
from koopbridge import InvalidInput, SimulatorAdapter  # noqa: E402
from koopbridge.adapters.mujoco import model as mujoco_model  # noqa: E402
from koopbridge.adapters.mujoco.model import ModelError  # noqa: E402
from koopbridge.adapters.mujoco.sim import FrankaSimulator, SimFailure  # noqa: E402
from koopbridge.testing import listening_client  # noqa: E402


def test_bad_commands_and_resets_in_process():
    sim = FrankaSimulator()
    with pytest.raises(InvalidInput, match="not reset yet"):
        sim.step(np.zeros(7))
    x = sim.reset(seed=1)
    with pytest.raises(InvalidInput, match="u must have 7 values, got 6"):
        sim.step(np.zeros(6))
    with pytest.raises(InvalidInput, match="u must be finite"):
        sim.step([0, 0, np.nan, 0, 0, 0, 0])
    bad = x.copy()
    bad[3 + 3] = 0.5  # joint4's range is [-3.0718, -0.0698]
    with pytest.raises(InvalidInput, match=r"x0: joint4 = 0.5 rad is outside its limits \[-3.0718, -0.0698\]"):
        sim.reset(x0=bad)
    with pytest.raises(InvalidInput, match="x0 must have 17 values, got 14"):
        sim.reset(x0=x[3:])
    # None of these touched the state.
    np.testing.assert_array_equal(sim.state(), x)


def test_unstable_step_is_a_failure_and_a_reset_recovers(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs its warnings to ./MUJOCO_LOG.TXT
    sim = FrankaSimulator()
    sim.reset(seed=2)
    sim.data.qvel[0] = np.nan  # what a blown-up integration leaves behind
    with pytest.raises(SimFailure, match="unstable at step 0 .*reset to go on"):
        sim.step(np.zeros(7))
    with pytest.raises(InvalidInput, match="reset needed after a failure"):
        sim.step(np.zeros(7))
    x = sim.reset(seed=2)
    assert np.all(np.isfinite(sim.step(np.full(7, 0.1)))) and np.all(np.isfinite(x))


def test_typed_errors_over_zenoh_and_serving_goes_on(session_id, serve_in_thread, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs its warnings to ./MUJOCO_LOG.TXT
    sim = FrankaSimulator()
    client, ep = listening_client(session_id)
    with serve_in_thread(SimulatorAdapter(sim), session=session_id, id="arm", connect=[ep]) as served:
        with client as c:
            c.connect_sim("arm", timeout=20)
            x = c.reset("arm", seed=3)
            cases = [
                (lambda: c.step("arm", np.zeros(6)), "dimension", "u has 6 values"),
                (lambda: c.step("arm", [np.nan] * 7), "bad_request", "u is not finite"),
                (lambda: c.reset("arm", x0=np.r_[x[:3], np.full(7, 4.0), np.zeros(7)]), "bad_request", "joint1 = 4 rad is outside its limits"),
            ]
            for call, code, text in cases:
                with pytest.raises(koopbridge.RemoteError) as e:
                    call()
                assert e.value.code == code and text in str(e.value), str(e.value)
            # The refused reset left the episode as it was: stepping continues at k = 1.
            k, _, _ = c.step("arm", np.full(7, 0.1))
            assert k == 1
            sim.data.qvel[2] = np.nan
            with pytest.raises(koopbridge.RemoteError) as e:
                c.step("arm", np.zeros(7))
            assert e.value.code == "sim_failure" and "SimFailure" in str(e.value) and "unstable" in str(e.value)
            np.testing.assert_array_equal(c.reset("arm", seed=3), x)
            assert c.step("arm", np.zeros(7))[0] == 1
    assert served.error is None, served.error
    assert served.stats["errors"] == 4 and served.stats["resets"] == 2


def test_missing_and_malformed_model_files(tmp_path):
    with pytest.raises(ModelError, match=r"MuJoCo model '.*nothing\.xml': file not found"):
        FrankaSimulator(str(tmp_path / "nothing.xml"))
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><worldbody><body></mujoco>")
    with pytest.raises(ModelError, match=r"MuJoCo model '.*broken\.xml': cannot parse it"):
        FrankaSimulator(str(broken))
    no_arm = tmp_path / "no_arm.xml"
    no_arm.write_text('<mujoco><worldbody><body name="b"><joint name="joint1"/><geom size="0.1"/></body></worldbody></mujoco>')
    with pytest.raises(ModelError, match=r"no_arm\.xml': no joint joint2, joint3"):
        FrankaSimulator(str(no_arm))
    # A model whose mesh file is missing fails at compile time, naming the model.
    src = mujoco_model.robosuite_panda_xml()
    text = open(src).read().replace('file="meshes/link0.stl"', 'file="meshes/gone.stl"')
    moved = tmp_path / "panda_missing_mesh.xml"
    moved.write_text(text.replace('file="meshes/', f'file="{src.rsplit("/", 1)[0]}/meshes/').replace('file="obj_meshes/', f'file="{src.rsplit("/", 1)[0]}/obj_meshes/'))
    with pytest.raises(ModelError, match=r"panda_missing_mesh\.xml': cannot (compile|parse) it .*gone\.stl"):
        FrankaSimulator(str(moved))


def test_without_robosuite_the_message_says_what_to_install(monkeypatch):
    monkeypatch.setattr(mujoco_model.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(ModelError, match=r"robosuite==1\.5\.2, which is not installed .*--model FILE"):
        mujoco_model.robosuite_panda_xml()


def test_command_line_names_the_bad_model_file(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "koopbridge.adapters.mujoco", "--model", str(tmp_path / "arm.xml")], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 2 and "arm.xml': file not found" in out.stderr, out.stderr
