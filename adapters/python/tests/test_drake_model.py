"""The Gen3 model Drake builds from robosuite's MJCF: forward kinematics and gravity torques
against MuJoCo on the original file (an independent implementation), limits, the cache."""

from __future__ import annotations

import numpy as np
import pytest

from koopbridge.adapters.drake.model import (
    LINK_NAMES,
    POSITION_LIMITS,
    VELOCITY_LIMITS,
    build_gen3,
    cleaned_mjcf,
    robosuite_mjcf,
)

mujoco = pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def mj():
    m = mujoco.MjModel.from_xml_path(str(robosuite_mjcf()))
    return m, mujoco.MjData(m)


def _random_q(rng, n):
    hi = np.where(np.isinf(POSITION_LIMITS), np.pi, POSITION_LIMITS)
    return rng.uniform(-hi, hi, size=(n, 7))


def test_forward_kinematics_matches_mujoco(mj):
    m, d = mj
    gen3 = build_gen3(collision=False)
    plant = gen3.plant
    ctx = plant.CreateDefaultContext()
    bodies = gen3.link_bodies()
    assert m.nq == 7
    worst = 0.0
    for q in _random_q(np.random.default_rng(7), 25):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        plant.SetPositions(ctx, q)
        for name, body in zip(LINK_NAMES, bodies, strict=False):
            X = plant.EvalBodyPoseInWorld(ctx, body)
            i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
            worst = max(worst, float(np.max(np.abs(X.translation() - d.xpos[i]))))
            np.testing.assert_allclose(X.rotation().matrix(), d.xmat[i].reshape(3, 3), atol=1e-6)
    assert worst < 1e-4, worst
    # The flange really moves: a wrong joint order or axis would not leave it at one place.
    d.qpos[:] = 0
    mujoco.mj_kinematics(m, d)
    top = d.xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "right_hand")].copy()
    assert 1.1 < top[2] < 1.4  # the Gen3 upright is about 1.25 m tall with its base at 0


def test_gravity_torques_match_mujoco(mj):
    m, d = mj
    gen3 = build_gen3(collision=False)
    plant = gen3.plant
    ctx = plant.CreateDefaultContext()
    for q in _random_q(np.random.default_rng(3), 10):
        d.qpos[:] = q
        d.qvel[:] = 0
        mujoco.mj_forward(m, d)
        plant.SetPositions(ctx, q)
        tau_g = plant.CalcGravityGeneralizedForces(ctx)
        # MuJoCo's bias force at rest is what holds the arm up: minus Drake's gravity force. The
        # cleaned copy adds 1e-6 kg at the flange, so 1e-4 N·m of slack.
        np.testing.assert_allclose(-tau_g, d.qfrc_bias, atol=1e-4)
        assert np.max(np.abs(tau_g)) > 0.5


def test_limits_and_cleaned_copy():
    gen3 = build_gen3(collision=True)
    plant = gen3.plant
    np.testing.assert_array_equal(plant.GetPositionUpperLimits(), POSITION_LIMITS)
    np.testing.assert_array_equal(plant.GetPositionLowerLimits(), -POSITION_LIMITS)
    np.testing.assert_array_equal(plant.GetVelocityUpperLimits(), VELOCITY_LIMITS)
    p = cleaned_mjcf(collision=True)
    assert cleaned_mjcf(collision=True) == p  # cached by content
    text = p.read_text()
    assert ".STL" not in text and ".stl" not in text
    assert text.count('type="mesh"') == 8  # base and seven links' collision meshes, no visual copies
    objs = sorted(x.name for x in p.parent.glob("*.obj"))
    assert len(objs) == 8 and "shoulder_link.obj" in objs
    inspector = gen3.scene_graph.model_inspector()
    # Collision geometry on every moving link and the table.
    for body in gen3.link_bodies()[:-1]:
        assert plant.GetCollisionGeometriesForBody(body), body.name()
    assert inspector.GetName(gen3.table) == "table"
    bare = cleaned_mjcf(collision=False)
    assert bare != p and 'type="mesh"' not in bare.read_text()
