"""The robot-agnostic legged pieces under the Go2 against independent computations: rotations
against MuJoCo's own quaternion routines, the torque lag against its closed form, fall
thresholds, target clipping, the model layout's errors and the expert's observation layout."""

from __future__ import annotations

import math

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from koopbridge.adapters.legged.common import (  # noqa: E402
    FallRule,
    LeggedLayout,
    PdDrive,
    body_from_world,
    clip_targets,
    projected_gravity,
    quat_to_matrix,
    tilt,
)
from koopbridge.adapters.legged.policy import ObservationLayout  # noqa: E402

ARM = """<mujoco><compiler angle="radian"/><option gravity="0 0 0" timestep="0.001"/><worldbody>
<body name="base"><freejoint/><geom size="0.1" mass="1"/>
<body name="link"><joint name="j" axis="0 1 0" range="-1 1"/><geom size="0.05" pos="0 0 -0.2" mass="0.5"/></body>
</body></worldbody><actuator><motor joint="j" ctrlrange="-2 2"/></actuator></mujoco>"""


def _quats(n: int) -> np.ndarray:
    q = np.random.default_rng(0).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_rotations_match_mujoco():
    for q in _quats(20):
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, q)
        np.testing.assert_allclose(quat_to_matrix(q), mat.reshape(3, 3), atol=1e-15)
        v = np.array([0.3, -1.2, 0.7])
        conj, out = np.zeros(4), np.zeros(3)
        mujoco.mju_negQuat(conj, q)
        mujoco.mju_rotVecQuat(out, v, conj)
        np.testing.assert_allclose(body_from_world(q, v), out, atol=1e-15)
        mujoco.mju_rotVecQuat(out, np.array([0.0, 0.0, -1.0]), conj)
        np.testing.assert_allclose(projected_gravity(q), out, atol=1e-15)
        assert tilt(q) == pytest.approx(math.acos(mat[8]), abs=1e-7)


def test_fall_rule_and_clipping():
    rule = FallRule(min_height=0.15, max_tilt=1.0)
    upright = np.array([1.0, 0, 0, 0])
    rolled = lambda a: np.array([math.cos(a / 2), math.sin(a / 2), 0, 0])  # noqa: E731
    assert not rule.fallen(upright, 0.3) and rule.fallen(upright, 0.14)
    assert not rule.fallen(rolled(0.99), 0.3) and rule.fallen(rolled(1.01), 0.3) and rule.fallen(rolled(math.pi), 0.3)
    clipped, n = clip_targets(np.array([-2.0, 0.0, 0.5, 3.0]), np.full(4, -1.0), np.full(4, 1.0))
    assert n == 2 and clipped.tolist() == [-1.0, 0.0, 0.5, 1.0]


def test_the_torque_lag_has_its_closed_form():
    m = mujoco.MjModel.from_xml_string(ARM)
    lay = LeggedLayout.from_model(m, ["j"], "base")
    assert lay.torque_limit.tolist() == [2.0] and (lay.q_min[0], lay.q_max[0]) == (-1.0, 1.0) and lay.base_qpos == 0
    tau, dt = 0.01, m.opt.timestep
    drive = PdDrive(lay, kp=1000.0, kd=0.0, tau=tau, dt=dt)
    d = mujoco.MjData(m)
    # A target 1 rad away with kp 1000 saturates the motor at +2 N·m every substep: the applied
    # torque is then the lag's step response 2 (1 − (1 − α)^n), α = dt / (tau + dt).
    alpha = dt / (tau + dt)
    for n in (1, 5, 20):
        drive.reset()
        mujoco.mj_resetData(m, d)
        drive.run(mujoco, m, d, np.array([1.0]), n)
        assert drive.applied[0] == pytest.approx(2.0 * (1 - (1 - alpha) ** n), rel=1e-12)
        assert d.ctrl[0] == drive.applied[0]
    # Without the lag the motor gets the clipped PD torque at once.
    direct = PdDrive(lay, kp=1.0, kd=0.5, tau=0.0, dt=dt)
    mujoco.mj_resetData(m, d)
    d.qvel[6] = 0.4
    direct.run(mujoco, m, d, np.array([0.3]), 1)
    assert direct.applied[0] == pytest.approx(1.0 * 0.3 - 0.5 * 0.4, abs=1e-15)
    with pytest.raises(ValueError, match="tau must be finite"):
        PdDrive(lay, 1.0, 1.0, tau=-1.0, dt=dt)


def test_layout_errors_name_what_is_missing():
    m = mujoco.MjModel.from_xml_string(ARM)
    with pytest.raises(ValueError, match="no joint 'knee'"):
        LeggedLayout.from_model(m, ["knee"], "base")
    with pytest.raises(ValueError, match="body 'link' has no free joint"):
        LeggedLayout.from_model(m, ["j"], "link")
    no_motor = mujoco.MjModel.from_xml_string(ARM.replace('<motor joint="j" ctrlrange="-2 2"/>', ""))
    with pytest.raises(ValueError, match=r"no motor drives joint\(s\) \['j'\]"):
        LeggedLayout.from_model(no_motor, ["j"], "base")


def test_the_observation_layout():
    pytest.importorskip("onnxruntime")
    from koopbridge.adapters.legged.go2 import model as g
    from koopbridge.adapters.legged.policy import OnnxExpert

    try:
        path = g.package_files()[1]
    except g.ModelError as e:  # pragma: no cover
        pytest.skip(str(e))
    lay: ObservationLayout = g.OBSERVATION
    assert lay.n_obs == 45
    expert = OnnxExpert(path, lay)
    rng = np.random.default_rng(1)
    w, grav, cmd, q, qd = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3), rng.normal(size=12), rng.normal(size=12) * 1e4
    expert.last_action = rng.normal(size=12)
    obs = expert.observation(w, grav, cmd, q, qd)
    np.testing.assert_array_equal(obs[0:3], w * 0.25)
    np.testing.assert_array_equal(obs[3:9], np.r_[grav, cmd])
    np.testing.assert_array_equal(obs[9:21], q - np.array([0.0, 0.8, -1.5] * 4))
    np.testing.assert_array_equal(obs[21:33], np.clip(qd * 0.05, -100, 100))
    np.testing.assert_array_equal(obs[33:45], expert.last_action)
    targets = expert.act(w, grav, cmd, q, qd)
    np.testing.assert_allclose(targets, np.array(g.DEFAULT_POSE) + expert.last_action * np.array(g.ACTION_SCALE), rtol=0, atol=0)
