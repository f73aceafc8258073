"""Joint references for end-effector paths on the MuJoCo Panda: SPEC's figure-8 and
damped-least-squares inverse kinematics on MuJoCo's site Jacobians (with a null-space pull
towards a rest posture, since 7 joints position a 3-D point redundantly)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..._native import InvalidInput
from .sim import FrankaSimulator

__all__ = ["FIGURE8_START_OFFSET", "IkResult", "dls_ik", "figure8"]

#: SPEC: the arm starts this far from the figure-8's first point (m, in x, y, z).
FIGURE8_START_OFFSET = (0.0, 0.01, 0.043)


def figure8(steps: int = 3001, t0: float = 1.6, dt: float = 0.02) -> np.ndarray:
    """SPEC's end-effector target, ``(steps, 3)``: at ``t = t0 + dt k``, x = 0.3,
    y = 0.3 cos t / (1 + sin² t), z = 0.59 + 0.6 sin t cos t / (1 + sin² t)."""
    t = t0 + dt * np.arange(steps)
    den = 1.0 + np.sin(t) ** 2
    return np.stack([np.full_like(t, 0.3), 0.3 * np.cos(t) / den, 0.59 + 0.6 * np.sin(t) * np.cos(t) / den], axis=1)


class IkResult:
    """Joint angles ``q`` ``(n, 7)`` for ``n`` targets and the position error left at each
    (``error``, m)."""

    def __init__(self, q: np.ndarray, error: np.ndarray) -> None:
        self.q = q
        self.error = error


def dls_ik(
    sim: FrankaSimulator,
    targets: npt.ArrayLike,
    q0: npt.ArrayLike | None = None,
    *,
    damping: float = 1e-3,
    rest: npt.ArrayLike | None = None,
    null_gain: float = 0.05,
    tol: float = 1e-6,
    max_iter: int = 200,
) -> IkResult:
    """For each target in turn (warm-started from the previous solution, the first from
    ``q0``, default home): ``dq = Jᵀ (J Jᵀ + damping² I)⁻¹ e + null_gain (I − J⁺ J)(rest − q)``
    with ``J`` MuJoCo's 3×7 positional Jacobian of the end-effector site, ``q`` clipped to the
    joint limits, until ``|e| < tol`` or ``max_iter``. ``rest`` defaults to home. Uses its own
    ``MjData``: the simulator's state is untouched."""
    mj = sim._mj
    m = sim.model
    d = mj.MjData(m)
    pts = np.asarray(targets, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.all(np.isfinite(pts)):
        raise InvalidInput(f"IK targets must be finite points of shape (n, 3), got {pts.shape}")
    q = sim.home.copy() if q0 is None else np.clip(np.asarray(q0, float), sim.q_lo, sim.q_hi)
    rest_q = sim.home.copy() if rest is None else np.asarray(rest, float)
    jacp = np.zeros((3, m.nv))
    cols = sim.vadr
    out = np.empty((len(pts), 7))
    err = np.empty(len(pts))
    eye = np.eye(3) * damping**2
    for i, target in enumerate(pts):
        for _ in range(max_iter):
            d.qpos[sim.qadr] = q
            mj.mj_kinematics(m, d)
            mj.mj_comPos(m, d)
            e = target - d.site_xpos[sim.arm.ee_site]
            if np.linalg.norm(e) < tol:
                break
            mj.mj_jacSite(m, d, jacp, None, sim.arm.ee_site)
            J = jacp[:, cols]
            JJt = J @ J.T
            dq = J.T @ np.linalg.solve(JJt + eye, e)
            pinv = J.T @ np.linalg.solve(JJt + eye, np.eye(3))
            dq += null_gain * (np.eye(7) - pinv @ J) @ (rest_q - q)
            q = np.clip(q + dq, sim.q_lo, sim.q_hi)
        d.qpos[sim.qadr] = q
        mj.mj_kinematics(m, d)
        out[i] = q
        err[i] = np.linalg.norm(target - d.site_xpos[sim.arm.ee_site])
    return IkResult(out, err)
