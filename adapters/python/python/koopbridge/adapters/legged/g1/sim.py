"""The Unitree G1 humanoid in MuJoCo as a discrete-time ``koopbridge.Simulator``: 23 joint position
targets held over 0.02 s by position servos (4 × 0.005 s, implicitfast), the other 6 joints held
at the default pose (by their servos, or locked); the trimmed 53-D state; falls detected and counted; the holosoma walking
policy as the ``expert`` / ``expert+noise`` collect policies. Model, policy and every constant:
``legged.g1.model``. No networking here (see ``legged.g1.__main__``).

Inputs ``u`` (23): targets of ``legged.g1.model.INPUT_JOINTS`` — the 29 joints without waist roll and
pitch and the wrist pitch and yaw (the paper's 23-input G1). Those six are held at the default
pose (0 rad), ``held="servo"`` (default) by their own servos — they give under load, the waist
roll/pitch by up to ~0.2 rad at ~1.4 rad/s while walking — or ``held="locked"``: removed from
the model, their links rigid (the 23-DoF G1 hardware; the expert walks either way).

State ``x`` (53), the Go2's 35-D pattern ``[base orientation quaternion (w, x, y, z) 4, base
linear velocity in the body frame 3, base angular velocity in the body frame 3, q 21, q̇ 21,
base (pelvis) height 1]`` over the 21 joints ``legged.g1.model.STATE_JOINTS``: the 23 input joints
without the two wrist rolls (their targets stay inputs). 11 + 2·21 = 53. Kept over the other
selections that give 53 (projected gravity + angular velocity + height + 23 joints, dropping the
base velocity; quaternion + angular velocity + 23 joints, dropping velocity and height) because
it keeps every base term the Go2 has, so the legged tooling (fall rule, ``reset(x0)``, joint
errors) reads both robots alike. Measured (``g1_replay``, 10 references of 200 steps): replaying
the expert's targets from ``reset(x0)`` with the wrist rolls restored exactly or at the default
pose makes no difference (36.2 steps either way, servo-held); restoring the six servo-held
joints exactly makes it 198.2 — the held joints, not the wrist rolls, are the state this
selection misses, and ``held="locked"`` removes them (floor 198.6 over 50 references).

``reset(x0=x)``: as the Go2's — a state this simulator returned (or started a collected window
at), among its last ``memory`` ones, is restored exactly (base x/y, the unobserved joints, the
solver's warm start); any other is placed at x = y = 0 with its orientation and velocities, the
joints outside the state (the wrist rolls; the six servo-held ones) at the default pose and at
rest, a cold solver.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ...._native import KoopbridgeError
from ....simulator import SimInfo
from ..collect import ExpertPolicy
from ..common import SimFailure, legged_state_names, legged_state_units, projected_gravity
from ..policy import OnnxExpert
from ..sim import LeggedSimulator
from . import model as g

__all__ = ["EXPERT_DEFAULTS", "G1Simulator", "SimFailure"]

#: The G1's expert collection defaults: commands over the policy's trained ranges (ONNX metadata
#: ``command_ranges``, ±1 m/s, ±1 m/s, ±1 rad/s), no slew limit (holosoma applies commands as given).
EXPERT_DEFAULTS: dict[str, object] = {"command_low": [-1.0, -1.0, -1.0], "command_high": [1.0, 1.0, 1.0]}


class G1Simulator(LeggedSimulator):
    """One G1 on flat ground in MuJoCo, stepped by 23 joint position targets.

    ``model``/``policy``: g1.xml and the ONNX expert (default: mjlab's model, holosoma's
    ``policy_name`` policy, ``fastsac`` or ``ppo``); the servo gains come from the policy's
    metadata. ``held``: ``servo`` or ``locked`` (module docstring). ``target_margin``: the input bounds are the joint ranges widened by this (rad);
    ``reset_range``: a seeded reset draws the 23 input joints from the default pose + U(±this)
    rad and the heading from U(±π); ``memory``: how many returned states ``reset(x0=)``
    restores exactly; ``env``: the name in ``info`` (default ``unitree-g1``, with locked holds
    ``unitree-g1-locked``, so that data of the two robots do not mix); ``on_fall``: called with
    a message at every fall.

    Counters: ``steps``, ``falls`` (upright → fallen transitions, lockstep and collect),
    ``clipped_targets``; ``fallen`` is the last step's status; ``step_status()`` gives the step
    reply's flags (``terminated`` while fallen, ``clipped``).
    """

    ROBOT = "G1"
    BASE_BODY = "pelvis"
    MASS_BODY = "torso_link"
    FALL = g.FALL
    START_HEIGHT = 1.0
    MAX_FOOT_PENETRATION = 0.03
    MODEL_ERROR = g.ModelError
    EXPERT_DEFAULTS = EXPERT_DEFAULTS

    def __init__(
        self,
        model: str | None = None,
        policy: str | None = None,
        *,
        policy_name: str = "fastsac",
        held: str = "servo",
        target_margin: float = 0.0,
        reset_range: float = 0.05,
        memory: int = 4096,
        env: str | None = None,
        on_fall: Callable[[str], None] | None = None,
    ) -> None:
        import mujoco

        policy_path = policy or g.policy_file(policy_name)
        meta = g.read_policy_meta(policy_path)
        self.g1 = g.build_g1(model, meta, held=held)
        self.held_mode = held
        self.model, self.layout = self.g1.model, self.g1.layout
        self.data = mujoco.MjData(self.model)
        self.substeps = self.g1.substeps
        self.dt = self.substeps * float(self.model.opt.timestep)
        try:
            self.expert = OnnxExpert(policy_path, g.OBSERVATION)
        except KoopbridgeError as e:
            raise g.ModelError(str(e)) from e
        # Index sets: ``present`` (policy order → the model's joints, the layout's order);
        # ``inputs``/``observed``: the input and state joints within the layout.
        present = list(self.layout.joints)
        self.present = np.array([g.JOINTS.index(j) for j in present])
        self.inputs = np.array([present.index(j) for j in g.INPUT_JOINTS])
        self.observed = np.array([present.index(j) for j in g.STATE_JOINTS])
        self.reset_joints = self.inputs
        self.state_joints = list(g.STATE_JOINTS)
        self.policy_default = g.default_pose()
        self.default_pose = self.policy_default[self.present]
        self.command_slew = np.full(3, np.inf)
        self.feet = [self.model.geom(f"{side}_foot{i}_collision").id for side in ("left", "right") for i in range(1, 8)]
        self._init_legged(
            mujoco,
            q_lo=self.layout.q_min[self.inputs],
            q_hi=self.layout.q_max[self.inputs],
            target_margin=target_margin,
            reset_range=reset_range,
            memory=memory,
            env=env or ("unitree-g1" if held == "servo" else "unitree-g1-locked"),
            on_fall=on_fall,
        )

    # ---- description ----
    def info(self) -> SimInfo:
        """Names, units, bounds (the joint limits), dt and everything the adapter does, as a ``SimInfo``."""
        lay = self.layout
        short = [j.removesuffix("_joint") for j in g.STATE_JOINTS]
        meta = self.g1.meta
        return SimInfo(
            env=self.env,
            kind="mujoco",
            version=f"MuJoCo {self._mj.__version__}",
            dt=self.dt,
            state_names=legged_state_names(short),
            input_names=[f"{j.removesuffix('_joint')}_target" for j in g.INPUT_JOINTS],
            u_min=self.u_lo.tolist(),
            u_max=self.u_hi.tolist(),
            extra=dict(
                mujoco=dict(
                    version=self._mj.__version__,
                    model_file=self.g1.path,
                    policy_file=self.expert.path,
                    source=f"{g.MODEL_PACKAGE}=={g.package_version(g.MODEL_PACKAGE) or g.MODEL_VERSION}: g1.xml (Apache-2.0); "
                    f"{g.POLICY_PACKAGE}=={g.package_version(g.POLICY_PACKAGE) or g.POLICY_VERSION}: holosoma walking policy "
                    "(no licence file in the wheel; upstream amazon-far/holosoma: Apache-2.0)",
                    joints=list(g.JOINTS),
                    input_joints=list(g.INPUT_JOINTS),
                    held_joints={j: float(self.policy_default[g.JOINTS.index(j)]) for j in g.HELD},
                    held=self.held_mode + (": the six joints' servos hold the default pose (they give under load)" if self.held_mode == "servo"
                                           else ": the six joints removed, their links rigid at the default pose (the 23-DoF G1)"),
                    state_joints=list(g.STATE_JOINTS),
                    state="53 = base quaternion w,x,y,z (4) + base linear velocity, body frame (3) + base angular velocity, "
                    "body frame (3) + q (21) + qd (21) of state_joints (the 23 input joints without the wrist rolls) + pelvis height (1)",
                    units=dict(state=legged_state_units(len(g.STATE_JOINTS)), input=["rad"] * self.nu),
                    actuation=dict(
                        servo="MuJoCo position actuator per joint: force = clip(kp (target - q) - kd qd, +-effort limit), implicit damping",
                        kp=list(meta.kp),
                        kd=list(meta.kd),
                        armature="kp / (2 pi 10 Hz)^2",
                        effort_limit=lay.torque_limit.tolist(),
                        targets=f"clipped to u_min, u_max (the joint ranges widened by {self.target_margin} rad), counted and flagged 'clipped' in the step reply",
                    ),
                    timestep=float(self.model.opt.timestep),
                    substeps=self.substeps,
                    integrator="implicitfast",
                    default_pose=list(g.DEFAULT_POSE),
                    fall=g.FALL.to_json(),
                    reset_range=self.reset_range,
                    expert=dict(
                        observation="holosoma loco_g1_29dof, sorted terms: [last action 29, ang_vel*0.25 3, yaw-rate command 1, "
                        "(vx, vy) command 2, cos phase 2, q - default 29, qd*0.05 29, projected gravity 3, sin phase 2]; "
                        "1 s gait phase, both feet at pi on a zero command",
                        action_scale=g.ACTION_SCALE,
                        command_ranges=meta.command_ranges,
                        collect_policies=["expert", "expert+noise"],
                        defaults=ExpertPolicy.from_json({"kind": "expert", **EXPERT_DEFAULTS}).to_json(),
                        held="the expert's targets for the 6 held joints are replaced by the default pose",
                    ),
                    x0="base x = y = 0, orientation from the quaternion, body-frame velocities rotated to the world, the joints "
                    f"outside the state at the default pose and at rest; a state among the last {self.memory} returned (or collected "
                    "window starts) is restored exactly",
                )
            ),
        )

    # ---- the robot's hooks (``LeggedSimulator``) ----
    def _lowest_foot(self, d: Any) -> float:
        """The lowest point (z) of the foot capsules."""
        m = self.model
        low = math.inf
        for f in self.feet:
            axis = np.asarray(d.geom_xmat[f]).reshape(3, 3)[:, 2] * m.geom_size[f][1]
            z = float(d.geom_xpos[f][2])
            low = min(low, z - abs(float(axis[2])) - float(m.geom_size[f][0]))
        return low

    def _full_targets(self, u: np.ndarray) -> np.ndarray:
        targets = self.default_pose.copy()
        targets[self.inputs] = u
        return targets

    def _hold(self, d: Any, q: np.ndarray) -> None:
        """The position servos' targets at ``q``."""
        d.ctrl[self.layout.actuators] = q

    def _actuate(self, targets: np.ndarray) -> None:
        """The 23 targets (the 6 held joints at the default pose) to the position servos."""
        m, d, mj = self.model, self.data, self._mj
        d.ctrl[self.layout.actuators] = self._full_targets(targets)
        for _ in range(self.substeps):
            mj.mj_step(m, d)

    # ---- the expert ----
    def expert_targets(self, command: np.ndarray) -> np.ndarray:
        """The expert's targets of the 23 input joints for the current state and ``command``
        (vx, vy, ωz); the expert observes all 29 joints (locked ones at the default pose, at rest)."""
        lay, d = self.layout, self.data
        v = lay.base_dof
        q, qd = self.policy_default.copy(), np.zeros(len(g.JOINTS))
        q[self.present], qd[self.present] = d.qpos[lay.qpos], d.qvel[lay.dofs]
        full = self.expert.act(np.array(d.qvel[v + 3 : v + 6]), projected_gravity(lay.quat(d)), command, q, qd)
        return full[self.present[self.inputs]]
