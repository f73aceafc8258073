"""The Drake Gen3 simulator with real Drake: velocity commands are tracked, the holding torque is
MuJoCo's gravity bias on the same MJCF, bad input is typed, ``collect_plans`` executes planned
trajectories into windows, and the adapter serves it over Zenoh and keeps serving after errors."""

from __future__ import annotations

import numpy as np
import pytest

import koopbridge
from koopbridge import InvalidInput
from koopbridge.adapters.drake.model import VELOCITY_LIMITS, robosuite_mjcf
from koopbridge.adapters.drake.sim import DrakeGen3Sim
from koopbridge.serving import SimulatorAdapter
from koopbridge.testing import check_adapter, listening_client


@pytest.fixture(scope="module")
def sim():
    return DrakeGen3Sim()


def test_info(sim):
    info = sim.info()
    assert info["kind"] == "drake" and info["dt"] == 0.001 and len(info["state_names"]) == 14
    assert info["u_max"] == VELOCITY_LIMITS.tolist() and info["drake"]["version"] in info["version"]


def test_velocity_commands_are_tracked(sim):
    q0 = np.array([0.3, 0.5, -0.2, 1.0, 0.1, -0.4, 0.2])
    x = sim.reset(x0=np.concatenate([q0, np.zeros(7)]))
    np.testing.assert_array_equal(x[:7], q0)
    u = np.array([0.4, -0.3, 0.5, -0.2, 0.6, 0.3, -0.5])
    xs = [x]
    for _ in range(500):
        x = sim.step(u)
        xs.append(x)
    assert sim.k == 500 and sim.context.get_time() == pytest.approx(0.5, abs=1e-12)
    # One plant update per step, never skipped: q_{k+1} = q_k + dt·qd_{k+1} (the discrete plant).
    xs = np.array(xs)
    np.testing.assert_allclose(np.diff(xs[:, :7], axis=0), 0.001 * xs[1:, 7:], atol=1e-12)
    np.testing.assert_allclose(x[7:], u, atol=2e-3)  # velocity tracked after 0.5 s
    # Velocity servo (the reference restarts at q every step): q lags q0 + t·u by the velocity's
    # rise (time constant 1/kd, longer where the effort limits clip the first torques).
    np.testing.assert_allclose(x[:7], q0 + 0.5 * u, atol=5e-3)
    for _ in range(300):
        x = sim.step(np.zeros(7))
    np.testing.assert_allclose(x[7:], 0, atol=2e-3)  # stops and holds
    # The arm ends near where the commands integrate to (the rise and fall transients differ
    # where the effort limits clip) and, with no position loop, holds there without drifting.
    np.testing.assert_allclose(x[:7], q0 + 0.5 * u, atol=5e-3)
    for _ in range(200):
        x2 = sim.step(np.zeros(7))
    np.testing.assert_allclose(x2[:7], x[:7], atol=1e-6)


def test_a_command_gain_scales_what_the_actuators_realise():
    slow = DrakeGen3Sim(command_gain=0.5)
    assert slow.info().extra["drake"]["controller"]["command_gain"] == 0.5
    q0 = np.array([0.3, 0.5, -0.2, 1.0, 0.1, -0.4, 0.2])
    u = np.array([0.4, -0.3, 0.5, -0.2, 0.6, 0.3, -0.5])
    x = slow.reset(x0=np.concatenate([q0, np.zeros(7)]))
    for _ in range(500):
        x = slow.step(u)
    np.testing.assert_allclose(x[7:], 0.5 * u, atol=2e-3)  # the velocity reached is half the command
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(InvalidInput):
            DrakeGen3Sim(command_gain=bad)


def test_a_reset_perturbation_sets_the_episodes_command_gain_and_the_next_reset_restores_it(sim):
    """The same arm as a simulator built with the gain: the perturbation lasts one episode."""
    x0 = np.concatenate([np.array([0.3, 0.5, -0.2, 1.0, 0.1, -0.4, 0.2]), np.zeros(7)])
    u = np.array([0.4, -0.3, 0.5, -0.2, 0.6, 0.3, -0.5])

    def run(s, **reset):
        s.reset(x0=x0, **reset)
        return np.array([s.step(u) for _ in range(50)])

    slow = run(DrakeGen3Sim(command_gain=0.9))
    np.testing.assert_array_equal(run(sim, perturbation={"command_gain": 0.9}), slow)
    nominal = run(sim)
    assert np.abs(nominal - slow).max() > 1e-3
    np.testing.assert_array_equal(run(sim, perturbation={}), nominal)
    for bad in ({"command_gain": 0.0}, {"command_gain": float("nan")}, {"command_gain": "x"}, {"mass_scale": 1.2}):
        with pytest.raises(InvalidInput, match="perturbation"):
            sim.reset(x0=x0, perturbation=bad)
    np.testing.assert_array_equal(run(sim), nominal)  # a refused perturbation changed nothing


def test_holding_torque_is_mujocos_gravity_bias(sim):
    mujoco = pytest.importorskip("mujoco")
    m = mujoco.MjModel.from_xml_path(str(robosuite_mjcf()))
    d = mujoco.MjData(m)
    q = np.array([0.5, 1.0, -0.3, 1.4, 0.2, -0.9, 0.0])
    sim.reset(x0=np.concatenate([q, np.zeros(7)]))
    d.qpos[:] = q
    mujoco.mj_forward(m, d)
    np.testing.assert_allclose(sim.torque(), d.qfrc_bias, atol=1e-3)
    for _ in range(200):
        x = sim.step(np.zeros(7))
    np.testing.assert_allclose(x[:7], q, atol=1e-4)


def test_bad_input_is_typed(sim):
    with pytest.raises(InvalidInput, match="outside its limits"):
        sim.reset(x0=[0, 2.5] + [0] * 12)
    with pytest.raises(InvalidInput, match="14 finite values"):
        sim.reset(x0=[0.0] * 13)
    with pytest.raises(InvalidInput, match="joint 1 velocity 2.9000 rad/s exceeds 2 x"):
        sim.reset(x0=[0.0] * 7 + [2.9] + [0.0] * 6)
    sim.reset(x0=[0.0] * 7 + [1.5] + [0.0] * 6)  # an overshoot the simulation reaches itself
    sim.reset(seed=3)
    x = sim.reset(seed=3)
    np.testing.assert_array_equal(x, sim.reset(seed=3))
    for bad, msg in (([0.0] * 6, "7 finite"), ([np.nan] + [0.0] * 6, "7 finite"), ([2.0] + [0.0] * 6, "exceeds its limit")):
        with pytest.raises(InvalidInput, match=msg):
            sim.step(bad)
    sim.step(np.zeros(7))  # still works


def test_collect_executes_plans_into_windows(sim):
    from koopbridge.adapters.drake.plan import Gen3Planner

    planner = Gen3Planner()
    goals = [[0.5, 0.4, 0.0, 0.8, 0.0, 0.5, 0.0], [0.0, 2.3, 0, 0, 0, 0, 0], [-0.3, 0.2, 0.3, 0.5, -0.4, 0.2, 0.6]]
    out = sim.collect_plans(planner, goals, steps=15)
    plans = out["plans"]
    assert plans[1]["error"]["code"] == "infeasible"  # laid into the table: skipped
    ok = [p for p in plans if "error" not in p]
    assert len(ok) == 2 and out["x"].shape == (sum(p["windows"] for p in ok), 16, 14) and out["u"].shape[1:] == (15, 7)
    assert all(p["final_error"] < 0.01 for p in ok)
    # Windows are consecutive pieces of one log: each starts where the previous ended.
    n0 = ok[0]["windows"]
    np.testing.assert_array_equal(out["x"][1 : n0, 0], out["x"][: n0 - 1, -1])
    # The commands are the planned velocities.
    plan = planner.plan(np.zeros(7), goals[0])
    _, _, qd = plan.sample(0.001)
    np.testing.assert_allclose(out["u"][:n0].reshape(-1, 7), qd[: n0 * 15], atol=1e-6)


def test_adapter_over_zenoh_keeps_serving_after_errors(serve_in_thread, session_id):
    client, ep = listening_client(session_id)
    adapter = SimulatorAdapter(DrakeGen3Sim())
    with serve_in_thread(adapter, session=session_id, id="gen3", connect=[ep]):
        with client as c:
            info = c.connect_sim("gen3", timeout=20)
            assert info["kind"] == "drake" and info["extra"]["drake"]["joints"][0] == "Actuator1"
            x = c.reset("gen3", seed=1)
            assert x.shape == (14,)
            with pytest.raises(koopbridge.RemoteError) as e:
                c.step("gen3", [np.nan] * 7)
            assert e.value.code == "bad_request"
            with pytest.raises(koopbridge.RemoteError) as e:
                c.step("gen3", [0.0] * 6)
            assert e.value.code in ("dimension", "bad_request")
            k, t, x1 = c.step("gen3", [0.1] * 7)
            assert k == 1 and t == pytest.approx(0.001)


def test_command_line_describe_and_bad_dt():
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "koopbridge.adapters.drake_sim", "--describe"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout)
    assert info["kind"] == "drake" and info["drake"]["controller"]["kp"] == 3600.0
    out = subprocess.run([sys.executable, "-m", "koopbridge.adapters.drake_sim", "--dt", "0.0015"], capture_output=True, text=True)
    assert out.returncode == 2 and "whole number of plant steps" in out.stderr



def test_check_adapter_passes_on_the_drake_simulator():
    """The SDK's adapter check (in-process and over a real Zenoh session): [q, q̇] is the whole
    state, so reset(x0=x_k) then step(u_k) reproduces x_{k+1} of the run."""
    sim = DrakeGen3Sim()
    try:
        info = check_adapter(sim, steps=6)
        assert info.nx == 14 and info.nu == 7 and info.kind == "drake"
    finally:
        sim.close()


def test_state_is_complete_mid_motion(sim):
    """Restarting from a state reached after 200 steps of motion (not from rest) gives the same
    continuation, bit for bit: nothing of the controller is carried between steps."""
    us = np.random.default_rng(5).uniform(-VELOCITY_LIMITS, VELOCITY_LIMITS, (240, 7))
    sim.reset(x0=np.r_[0.2, 0.4, 0.0, 1.0, 0.0, 0.3, 0.0, np.zeros(7)])
    xs = [sim.step(u) for u in us]
    sim.reset(x0=xs[199])
    again = [sim.step(u) for u in us[200:]]
    np.testing.assert_array_equal(np.array(again), np.array(xs[200:]))
