"""SPEC's figure-8 task on the MuJoCo Panda: full-state references (IK joint angles, q̇_ref = 0),
the offset start state, the controllers compared (Koopman MPC through the service, zero input,
a joint-space P controller) and the tracking error."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from koopbridge.adapters.mujoco.ik import FIGURE8_START_OFFSET, dls_ik, figure8
from koopbridge.adapters.mujoco.sim import FrankaSimulator

__all__ = ["Figure8", "SKIP", "joint_p_command", "references", "tracking_error"]

#: SPEC: the error counts the steps after the first 100.
SKIP = 100


@dataclass
class Figure8:
    """The task: ``targets`` ``(n, 3)`` end-effector points, ``q`` ``(n, 7)`` IK joint
    references, ``x`` ``(n, nx)`` full-state references ``[target, q, 0]`` (``[q, 0]`` for
    the 14-D state), ``x0`` the start state (the first target + SPEC's offset, at rest), and
    ``ik_error`` the largest IK position error over the targets (m)."""

    targets: np.ndarray
    q: np.ndarray
    x: np.ndarray
    x0: np.ndarray
    ik_error: float

    def reference_window(self, k: int, horizon: int) -> np.ndarray:
        """References for the states ``x_{k+1} .. x_{k+horizon}`` (the last one held past the end)."""
        idx = np.minimum(np.arange(k + 1, k + 1 + horizon), len(self.x) - 1)
        return self.x[idx]


def references(sim: FrankaSimulator, steps: int) -> Figure8:
    """The figure-8 of ``steps`` points (SPEC: 3001) with joint references by damped least
    squares on ``sim``'s Jacobians, and the start state by IK at the offset first point."""
    targets = figure8(steps)
    ik = dls_ik(sim, targets)
    start = dls_ik(sim, (targets[0] + np.array(FIGURE8_START_OFFSET))[None, :], q0=ik.q[0])
    zeros = np.zeros((steps, 7))
    q_start = start.q[0]
    if sim.with_ee:
        x = np.concatenate([targets, ik.q, zeros], axis=1)
        x0 = np.concatenate([sim.ee_position(q_start), q_start, np.zeros(7)])
    else:
        x = np.concatenate([ik.q, zeros], axis=1)
        x0 = np.concatenate([q_start, np.zeros(7)])
    return Figure8(targets, ik.q, x, x0, float(max(ik.error.max(), start.error.max())))


def tracking_error(ee: np.ndarray, targets: np.ndarray, skip: int = SKIP) -> float:
    """SPEC's error: the Frobenius norm of the (y, z) deviation of the end-effector path from
    the targets over the steps after the first ``skip``."""
    if ee.shape != targets.shape:
        raise ValueError(f"path {ee.shape} and targets {targets.shape} differ")
    return float(np.linalg.norm(ee[skip:, 1:3] - targets[skip:, 1:3]))


def joint_p_command(q: np.ndarray, q_next: np.ndarray, gain: float, limit: float) -> np.ndarray:
    """The joint-space P baseline: ``clip(gain (q_ref_{k+1} − q_k), ±limit)`` (rad/s)."""
    return np.clip(gain * (q_next - q), -limit, limit)
