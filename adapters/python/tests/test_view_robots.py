"""The viewer's 3D robots (koopbridge.view.robots) against the simulators themselves: the pose the
viewer computes from a state is the simulator's own configuration (its MjData after the steps
that produced the state), for the Go2, the G1 and the Franka; a state of the wrong length or
with NaN is not posed; a Gymnasium id from the network is only ever a registered one."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

pytest.importorskip("rerun")
pytest.importorskip("mujoco")

from koopbridge.view.robots import robot_for  # noqa: E402


def info_of(sim: Any) -> dict[str, Any]:
    i = sim.info()
    return {"env": i.env, "state_names": list(i.state_names), "extra": i.extra}


def walk(sim: Any, steps: int) -> np.ndarray:
    """A few steps from a seeded reset toward the state's joint targets (inputs inside the bounds)."""
    x = np.asarray(sim.reset(seed=3))
    lo, hi = np.asarray(sim.info().u_min), np.asarray(sim.info().u_max)
    rng = np.random.default_rng(0)
    for _ in range(steps):
        x = np.asarray(sim.step(np.clip(lo + (hi - lo) * rng.uniform(0.3, 0.7, len(lo)), lo, hi)))
    return x


@pytest.mark.parametrize("robot", ["go2", "g1"])
def test_a_legged_state_poses_the_robot_as_the_simulator_holds_it(robot):
    if robot == "go2":
        from koopbridge.adapters.legged.go2.sim import Go2Simulator as Sim
    else:
        from koopbridge.adapters.legged.g1.sim import G1Simulator as Sim
    sim = Sim()
    x = walk(sim, 5)
    poser = robot_for(info_of(sim))
    assert poser is not None
    got = poser.qpos_of(x)
    want = np.array(sim.data.qpos)
    b = sim.layout.base_qpos
    # The base's x and y are not in the state (the viewer keeps the robot at the origin).
    np.testing.assert_allclose(got[b + 2 : b + 7], want[b + 2 : b + 7], atol=1e-12)
    joints = sim.layout.qpos[sim.observed]
    np.testing.assert_allclose(got[joints], want[joints], atol=1e-12)
    assert poser.qpos_of(x[:-1]) is None and poser.pose(np.full_like(x, np.nan)) is None
    sim.close()


def test_the_arm_state_poses_the_franka_as_the_simulator_holds_it():
    from koopbridge.adapters.mujoco.sim import FrankaSimulator

    sim = FrankaSimulator()
    x = walk(sim, 5)
    poser = robot_for(info_of(sim))
    assert poser is not None
    np.testing.assert_allclose(poser.qpos_of(x)[sim.qadr], np.array(sim.data.qpos)[sim.qadr], atol=1e-12)
    # The geoms land where the simulator has them.
    pos, _ = poser.pose(x)
    want = np.array(sim.data.geom_xpos)[poser.geoms]
    np.testing.assert_allclose(pos, want, atol=1e-9)


def test_only_registered_gymnasium_ids_with_plain_options_are_built():
    pytest.importorskip("gymnasium")
    gym = {"state": "qpos,qvel", "mujoco": {}, "make_kwargs": {}}
    assert robot_for({"env": "x", "extra": {"gymnasium": {**gym, "env_id": "InvertedPendulum-v5"}}}) is not None
    assert robot_for({"env": "x", "extra": {"gymnasium": {**gym, "env_id": "os:system"}}}) is None
    assert robot_for({"env": "x", "extra": {"gymnasium": {**gym, "env_id": "NoSuchEnv-v0"}}}) is None
    files = {**gym, "env_id": "InvertedPendulum-v5", "make_kwargs": {"xml_file": "/etc/passwd"}}
    assert robot_for({"env": "x", "extra": {"gymnasium": files}}) is None
    assert robot_for({"env": "damped-pendulum", "state_names": ["theta", "omega"]}) is None
