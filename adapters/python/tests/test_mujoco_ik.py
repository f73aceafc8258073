"""Joint references for SPEC's figure-8: the lemniscate itself, and damped-least-squares IK on
MuJoCo's Jacobians whose solutions put Franka's DH kinematics on every target."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mujoco")

from test_mujoco_sim import dh_position  # noqa: E402

from koopbridge import InvalidInput  # noqa: E402
from koopbridge.adapters.mujoco.ik import dls_ik, figure8  # noqa: E402
from koopbridge.adapters.mujoco.sim import FrankaSimulator  # noqa: E402


def test_figure8_is_specs_lemniscate():
    p = figure8()
    assert p.shape == (3001, 3) and np.all(p[:, 0] == 0.3)
    t = 1.6 + 0.02 * 1234
    np.testing.assert_allclose(p[1234], [0.3, 0.3 * np.cos(t) / (1 + np.sin(t) ** 2), 0.59 + 0.6 * np.sin(t) * np.cos(t) / (1 + np.sin(t) ** 2)])
    # Its extremes in closed form: y in ±0.3 (at sin t = 0), z in 0.59 ± 0.6/√8 (at sin² t = 1/3).
    assert abs(p[:, 1].max() - 0.3) < 1e-6 and abs(p[:, 1].min() + 0.3) < 1e-4
    assert abs(p[:, 2].max() - (0.59 + 0.6 / np.sqrt(8))) < 1e-4 and abs(p[:, 2].min() - (0.59 - 0.6 / np.sqrt(8))) < 1e-4


def test_ik_reaches_the_whole_figure8_within_the_joint_limits():
    sim = FrankaSimulator()
    x = sim.reset(seed=3)
    targets = figure8()
    r = dls_ik(sim, targets)
    assert r.q.shape == (3001, 7) and r.error.max() < 1e-6
    assert np.all(r.q >= sim.q_lo) and np.all(r.q <= sim.q_hi)
    # Independent check: Franka's DH kinematics of the solutions.
    for i in range(0, 3001, 150):
        np.testing.assert_allclose(dh_position(r.q[i]), targets[i], atol=2e-6)
    # Warm starts keep consecutive solutions close (no branch flips).
    assert np.abs(np.diff(r.q, axis=0)).max() < 0.05
    np.testing.assert_array_equal(sim.state(), x)  # the simulator's own state is untouched
    with pytest.raises(InvalidInput, match="shape \\(n, 3\\)"):
        dls_ik(sim, np.zeros((4, 2)))
