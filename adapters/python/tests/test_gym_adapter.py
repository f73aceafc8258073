"""The Gymnasium adapter (``koopbridge.adapters.gym``): InvertedPendulum-v5 and Reacher-v5 pass
``check_adapter`` over a real Zenoh session; served states equal a separate ``gymnasium.make``
environment stepped directly; ``reset(x0)`` sets the env's own MuJoCo state exactly; episode ends
are reported and stepping goes on; bad ids, non-Box actions and bad requests get clear errors;
the Gym scenario runs from outside the repository with a tiny budget."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")
pytest.importorskip("mujoco")

import koopbridge  # noqa: E402
from conftest import ROOT, Child, free_endpoint, koopbridge_binary_or_skip  # noqa: E402
from koopbridge import InvalidInput, SimulatorAdapter, Unsupported  # noqa: E402
from koopbridge.adapters.gym.sim import GymError, GymSimulator  # noqa: E402
from koopbridge.testing import check_adapter, listening_client, sample_inputs  # noqa: E402

ENVS = ("InvertedPendulum-v5", "Reacher-v5")


def _direct(env_id: str, **kw):
    """A separate environment, made and stepped with Gymnasium alone."""
    env = gymnasium.make(env_id, **kw)
    return env, env.unwrapped


@pytest.mark.parametrize("env_id", ENVS)
def test_check_adapter_over_zenoh(env_id):
    sim = GymSimulator(env_id)
    try:
        info = check_adapter(sim, steps=12)
    finally:
        sim.close()
    m = sim.mujoco
    assert info.kind == "gymnasium" and info.env == env_id and info.nx == m.nq + m.nv
    assert info.dt == pytest.approx(m.opt.timestep * sim.raw.frame_skip)
    env, _ = _direct(env_id)
    np.testing.assert_array_equal(info.u_min, env.action_space.low)
    np.testing.assert_array_equal(info.u_max, env.action_space.high)


def test_names_and_bounds_from_the_model():
    sim = GymSimulator("Reacher-v5")
    info = sim.info()
    assert info.state_names == ["joint0", "joint1", "target_x", "target_y", "joint0_vel", "joint1_vel", "target_x_vel", "target_y_vel"]
    assert info.input_names == ["joint0_cmd", "joint1_cmd"] and info.angle_indices == [0, 1]
    assert info.u_min == [-1.0, -1.0] and info.u_max == [1.0, 1.0] and info.dt == pytest.approx(0.02)
    assert info.extra["gymnasium"]["state"] == "qpos,qvel" and info.extra["gymnasium"]["mujoco"]["nq"] == 4
    sim.close()


@pytest.mark.parametrize("env_id", ENVS)
def test_served_steps_equal_direct_env_steps(env_id, session_id, serve_in_thread):
    """Seeded reset and steps over Zenoh equal a second environment stepped with env.step; a
    reset(x0) at a state no run produced equals that env after set_state, then one step."""
    sim = GymSimulator(env_id)
    info = sim.info()
    us = sample_inputs(info, 15, seed=4)
    env, raw = _direct(env_id)
    client, ep = listening_client(session_id)
    with serve_in_thread(SimulatorAdapter(sim), session=session_id, id="g", connect=[ep]) as served:
        with client as c:
            c.connect_sim("g", timeout=20)
            x = c.reset("g", seed=11)
            env.reset(seed=11)
            np.testing.assert_array_equal(x, raw.state_vector())
            for i, u in enumerate(us):
                k, t, x = c.step("g", u)
                env.step(u)  # u is float64 and inside the Box: the adapter passes it on as it is
                assert k == i + 1 and t == pytest.approx((i + 1) * info.dt)
                np.testing.assert_array_equal(x, raw.state_vector())
            # A state no run produced: set_state on both sides, then one step.
            rng = np.random.default_rng(5)
            x0 = np.r_[raw.data.qpos + rng.uniform(-0.05, 0.05, raw.model.nq), rng.uniform(-0.3, 0.3, raw.model.nv)]
            np.testing.assert_array_equal(c.reset("g", x0=x0), x0)
            env.reset(seed=0)
            raw.set_state(x0[: raw.model.nq], x0[raw.model.nq :])
            np.testing.assert_array_equal(raw.state_vector(), x0)
            _, _, x1 = c.step("g", us[0])
            env.step(us[0])
            np.testing.assert_array_equal(x1, raw.state_vector())
    assert served.error is None, served.error
    env.close()


def test_reset_x0_sets_the_env_state_exactly():
    sim = GymSimulator("Reacher-v5")
    sim.reset(seed=3)
    us = sample_inputs(sim.info(), 30, seed=3)
    xs = [sim.step(u) for u in us]
    # A returned state: the env's own state vector is x exactly, and stepping on repeats the run bit for bit.
    x = sim.reset(x0=xs[9])
    np.testing.assert_array_equal(x, xs[9])
    np.testing.assert_array_equal(sim.raw.state_vector(), xs[9])
    for j in range(10, 30):
        np.testing.assert_array_equal(sim.step(us[j]), xs[j])
    # An arbitrary state, through the env's set_state.
    x0 = np.array([0.3, -1.2, 0.1, -0.05, 0.5, -0.5, 0.0, 0.0])
    np.testing.assert_array_equal(sim.reset(x0=x0), x0)
    np.testing.assert_array_equal(sim.raw.data.qpos, x0[:4])
    np.testing.assert_array_equal(sim.raw.data.qvel, x0[4:])
    assert sim.status()["k"] == 0 and sim.env._elapsed_steps == 0  # a new episode for the time limit too
    sim.close()


def test_obs_state_is_the_observation():
    """--state obs: InvertedPendulum's observation is [qpos, qvel] (reset(x0) works); Reacher's
    is not (reset(x0) is Unsupported, seeded resets and steps give the observation)."""
    pend = GymSimulator("InvertedPendulum-v5", state="obs")
    assert pend.obs_is_state and pend.info().state_names == ["slider", "hinge", "slider_vel", "hinge_vel"]
    x0 = np.array([0.1, -0.05, 0.2, 0.3])
    np.testing.assert_array_equal(pend.reset(x0=x0), x0)
    obs, *_ = pend.env.step(np.array([0.5]))
    pend.reset(x0=x0)
    np.testing.assert_array_equal(pend.step([0.5]), obs)
    reacher = GymSimulator("Reacher-v5", state="obs")
    env, _ = _direct("Reacher-v5")
    obs, _ = env.reset(seed=2)
    np.testing.assert_array_equal(reacher.reset(seed=2), obs)
    obs, *_ = env.step(np.array([0.2, -0.3]))
    np.testing.assert_array_equal(reacher.step([0.2, -0.3]), obs)
    assert reacher.info().state_names[:2] == ["obs0", "obs1"] and reacher.nx == 10
    with pytest.raises(Unsupported, match=r"Reacher-v5: reset\(x0\) needs the full state.*use --state qpos,qvel"):
        reacher.reset(x0=np.zeros(10))
    pend.close()
    reacher.close()


def test_termination_is_reported_and_stepping_goes_on(session_id, serve_in_thread):
    ended: list[str] = []
    sim = GymSimulator("InvertedPendulum-v5", on_episode_end=ended.append)
    env, raw = _direct("InvertedPendulum-v5")
    client, ep = listening_client(session_id)
    with serve_in_thread(SimulatorAdapter(sim), session=session_id, id="p", connect=[ep]) as served:
        with client as c:
            c.connect_sim("p", timeout=20)
            c.reset("p", seed=1)
            env.reset(seed=1)
            fell = None
            for _ in range(40):
                k, _, x, status = c.step("p", [3.0], with_status=True)
                _, _, terminated, truncated, _ = env.step(np.array([3.0]))
                np.testing.assert_array_equal(x, raw.state_vector())
                assert sim.status()["terminated"] == terminated and not truncated
                # The step reply carries the separate environment's own termination flag.
                assert status == {"terminated": terminated, "truncated": False, "clipped": False}, (k, status)
                if terminated and fell is None:
                    fell = k
            # Gymnasium's own rule (|hinge| > 0.2) ended the episode; the adapter stepped on past it.
            assert fell is not None and fell < 40 and k == 40 and abs(x[1]) > 0.2
            assert sim.status()["terminations"] == 1 and sim.terminated
            assert ended == [f"InvertedPendulum-v5: episode terminated at step {fell} (reward 0); stepping goes on until the next reset"]
            # An action outside the Box (±3) is clipped, and the reply says so.
            assert c.step("p", [5.0], with_status=True)[3] == {"terminated": True, "truncated": False, "clipped": True}
            c.reset("p", seed=1)
            assert not sim.terminated and sim.status()["k"] == 0 and sim.status()["episodes"] == 2
    assert served.error is None, served.error
    env.close()


def test_truncation_is_reported_and_stepping_goes_on():
    ended: list[str] = []
    sim = GymSimulator("Reacher-v5", make_kwargs={"max_episode_steps": 5}, on_episode_end=ended.append)
    sim.reset(seed=0)
    for _ in range(5):
        sim.step([0.1, 0.1])
    assert sim.truncated and sim.status()["truncations"] == 1
    x = sim.step([0.1, 0.1])
    assert sim.k == 6 and np.all(np.isfinite(x)) and sim.status()["truncations"] == 1
    assert len(ended) == 1 and "episode truncated at step 5" in ended[0]
    assert sim.info().extra["gymnasium"]["max_episode_steps"] == 5
    sim.close()


def test_truncation_arrives_in_the_step_reply(session_id, serve_in_thread):
    sim = GymSimulator("Reacher-v5", make_kwargs={"max_episode_steps": 3}, on_episode_end=None)
    client, ep = listening_client(session_id)
    with serve_in_thread(SimulatorAdapter(sim), session=session_id, id="r", connect=[ep]) as served:
        with client as c:
            c.connect_sim("r", timeout=20)
            for episode in range(2):
                c.reset("r", seed=episode)
                got = [c.step("r", [0.05, -0.05], with_status=True)[3] for _ in range(5)]
                # Gymnasium's TimeLimit: truncated from step 3 on; stepping goes on past it.
                assert [s["truncated"] for s in got] == [False, False, True, True, True], got
                assert not any(s["terminated"] or s["clipped"] for s in got), got
    assert served.error is None, served.error
    assert sim.status()["truncations"] == 2


def test_bad_requests_get_typed_errors_and_serving_goes_on(session_id, serve_in_thread):
    sim = GymSimulator("Reacher-v5")
    with pytest.raises(InvalidInput, match="not reset yet"):
        sim.step([0.0, 0.0])
    client, ep = listening_client(session_id)
    with serve_in_thread(SimulatorAdapter(sim), session=session_id, id="r", connect=[ep]) as served:
        with client as c:
            c.connect_sim("r", timeout=20)
            x = c.reset("r", seed=3)
            cases = [
                (lambda: c.step("r", np.zeros(3)), "dimension", "u has 3 values"),
                (lambda: c.step("r", [np.nan, 0.0]), "bad_request", "u is not finite"),
                (lambda: c.reset("r", x0=np.zeros(7)), "dimension", "x0"),
            ]
            for call, code, text in cases:
                with pytest.raises(koopbridge.RemoteError) as e:
                    call()
                assert e.value.code == code and text in str(e.value), str(e.value)
            k, _, _ = c.step("r", [5.0, -5.0])  # outside the Box: clipped to [1, -1] and counted
            assert k == 1 and sim.clipped_inputs == 2
            np.testing.assert_array_equal(c.reset("r", seed=3), x)
            assert c.step("r", [0.0, 0.0])[0] == 1
    assert served.error is None, served.error
    assert served.stats["errors"] == 3


def test_bad_environments_are_refused_at_start_up():
    with pytest.raises(GymError, match=r"'InvertedPendulm-v5' does not exist .*close names: InvertedPendulum-v5"):
        GymSimulator("InvertedPendulm-v5")
    with pytest.raises(GymError, match=r"CartPole-v1: the action space is Discrete\(2\), not a Box"):
        GymSimulator("CartPole-v1")
    with pytest.raises(GymError, match="Pendulum-v1 is not MuJoCo-based .*use --state obs"):
        GymSimulator("Pendulum-v1", state="qpos,qvel")
    with pytest.raises(GymError, match=r"MountainCarContinuous-v0 does not say its time step .*give --dt SECONDS"):
        GymSimulator("MountainCarContinuous-v0")
    with pytest.raises(GymError, match=r"InvertedPendulum-v5 steps dt = 0\.04 s; --dt 0\.1 cannot change that"):
        GymSimulator("InvertedPendulum-v5", dt=0.1)
    with pytest.raises(GymError, match="could not be made with"):
        GymSimulator("Reacher-v5", make_kwargs={"no_such_option": 1})


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "koopbridge.adapters.gym", *args], capture_output=True, text=True, timeout=120)


def test_command_line_errors_name_the_thing():
    out = _cli("NoSuchEnv-v0", "--describe")
    assert out.returncode == 2 and "error: Gymnasium environment 'NoSuchEnv-v0' does not exist" in out.stderr, out.stderr
    out = _cli("CartPole-v1", "--describe")
    assert out.returncode == 2 and "error: CartPole-v1: the action space is Discrete(2), not a Box" in out.stderr, out.stderr
    out = _cli("Reacher-v5", "--make-kwargs", "[1]", "--describe")
    assert out.returncode == 2 and "--make-kwargs must be a JSON object" in out.stderr, out.stderr
    out = _cli("Reacher-v5", "--describe")
    assert out.returncode == 0 and '"kind": "gymnasium"' in out.stdout and '"joint0_vel"' in out.stdout, out.stderr


def test_command_line_serves_reports_falls_and_stops_with_the_lifeline(session_id, tmp_path):
    ep = free_endpoint()
    cmd = [sys.executable, "-m", "koopbridge.adapters.gym", "InvertedPendulum-v5", "--session", session_id, "--id", "pend", "--listen", ep, "--stdin-lifeline"]
    with Child(cmd, tmp_path / "gym.log") as child:
        with koopbridge.Client(session=session_id, connect=[ep]) as c:
            assert c.connect_sim("pend", timeout=60)["kind"] == "gymnasium"
            c.reset("pend", seed=1)
            for _ in range(30):
                k, _, _ = c.step("pend", [-3.0])
            assert k == 30
        child.p.stdin.close()
        assert child.p.wait(timeout=30) == 0, child.output()
        deadline = time.time() + 5
        while "stopped after" not in child.output() and time.time() < deadline:
            time.sleep(0.1)
        log = child.output()
    assert "InvertedPendulum-v5: episode terminated at step" in log and "stepping goes on" in log, log
    assert "stopped after 30 steps" in log and "'terminations': 1" in log, log


def test_scenario_outside_the_repository_runs_with_a_tiny_budget(tmp_path):
    """scenarios/gym-inverted-pendulum.toml copied outside the repository (no .venv beside it):
    `{python}` still resolves to a Python with koopbridge and says which; the run collects from
    the Gymnasium adapter, trains, controls and reports the environment's state names."""
    exe = koopbridge_binary_or_skip()
    text = (ROOT / "scenarios" / "gym-inverted-pendulum.toml").read_text()
    for key, value in (("train_windows", 64), ("val_windows", 16), ("test_windows", 16)):
        text = re.sub(rf"^{key} = \d+", f"{key} = {value}", text, count=1, flags=re.M)
    text = text.replace("steps = 300", "steps = 20").replace("iterations = 3000, validate_every = 500", "iterations = 40, validate_every = 20")
    sc = tmp_path / "elsewhere" / "gym.toml"
    sc.parent.mkdir()
    sc.write_text(text)
    out = tmp_path / "out"
    env = {k: v for k, v in os.environ.items() if k != "KOOPBRIDGE_PYTHON"}
    if not any((d / ".venv" / "bin" / "python").is_file() for d in exe.resolve().parents):
        env["KOOPBRIDGE_PYTHON"] = sys.executable  # a binary installed elsewhere: name the Python
    r = subprocess.run([str(exe), "run", str(sc), "--out", str(out)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert re.search(r"koopbridge: \{python\} is \S+ \((the venv of \S+, where this koopbridge was built|KOOPBRIDGE_PYTHON)\)", r.stderr), r.stderr[-2000:]
    report = json.loads((out / "report.json").read_text())
    c = report["control"]
    assert c["state_names"] == ["slider", "hinge", "slider_vel", "hinge_vel"] and c["input_names"] == ["slide"]
    assert c["dt"] == pytest.approx(0.04) and len(c["x"]) == 21 and np.all(np.isfinite(c["x"]))
