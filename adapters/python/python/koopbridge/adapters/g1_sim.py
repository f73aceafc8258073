"""The Unitree G1 humanoid in MuJoCo as a discrete-time ``koopbridge.Simulator``: 23 joint position
targets held over 0.02 s by position servos (4 × 0.005 s, implicitfast), the other 6 joints held
at the default pose (by their servos, or locked); the trimmed 53-D state; falls detected and counted; the holosoma walking
policy as the ``expert`` / ``expert+noise`` collect policies. Model, policy and every constant:
``g1_model``. No networking here (see ``g1.py``).

Inputs ``u`` (23): targets of ``g1_model.INPUT_JOINTS`` — the 29 joints without waist roll and
pitch and the wrist pitch and yaw (the paper's 23-input G1). Those six are held at the default
pose (0 rad), ``held="servo"`` (default) by their own servos — they give under load, the waist
roll/pitch by up to ~0.2 rad at ~1.4 rad/s while walking — or ``held="locked"``: removed from
the model, their links rigid (the 23-DoF G1 hardware; the expert walks either way).

State ``x`` (53), the Go2's 35-D pattern ``[base orientation quaternion (w, x, y, z) 4, base
linear velocity in the body frame 3, base angular velocity in the body frame 3, q 21, q̇ 21,
base (pelvis) height 1]`` over the 21 joints ``g1_model.STATE_JOINTS``: the 23 input joints
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
import sys
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from .._native import InvalidInput, KoopbridgeError, Unsupported
from ..collect import PlannedPolicy, Policy, SimulatorPolicy, UniformPolicy, Windows, collect_windows
from ..simulator import SimInfo, as_input, as_state
from . import g1_model as g
from .legged import (
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

__all__ = ["EXPERT_DEFAULTS", "G1Simulator", "SimFailure"]

#: How far (m) a reset state may push a foot geom / any other robot geom into the floor.
MAX_FOOT_PENETRATION = 0.03
MAX_PENETRATION = 0.02
#: How far (rad) a reset state's joint may be outside its range.
JOINT_SLACK = 0.2
#: The G1's expert collection defaults: commands over the policy's trained ranges (ONNX metadata
#: ``command_ranges``, ±1 m/s, ±1 m/s, ±1 rad/s), no slew limit (holosoma applies commands as given).
EXPERT_DEFAULTS = {"command_low": [-1.0, -1.0, -1.0], "command_high": [1.0, 1.0, 1.0]}



class G1Simulator:
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

        self._mj = mujoco
        policy_path = policy or g.policy_file(policy_name)
        meta = g.read_policy_meta(policy_path)
        self.g1 = g.build_g1(model, meta, held=held)
        self.held_mode = held
        self.model, self.layout = self.g1.model, self.g1.layout
        self.data = mujoco.MjData(self.model)
        self._probe = mujoco.MjData(self.model)
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
        self.policy_default = g.default_pose()
        self.default_pose = self.policy_default[self.present]
        q_min, q_max = self.layout.q_min[self.inputs], self.layout.q_max[self.inputs]
        if not (math.isfinite(target_margin) and target_margin >= 0):
            raise g.ModelError(f"target margin must be finite and >= 0, got {target_margin}")
        self.target_margin = float(target_margin)
        self.u_lo, self.u_hi = q_min - self.target_margin, q_max + self.target_margin
        self.command_slew = np.full(3, np.inf)
        self.reset_range = float(reset_range)
        self.env = env or ("unitree-g1" if held == "servo" else "unitree-g1-locked")
        self.on_fall = on_fall
        self.nx, self.nu = 11 + 2 * len(self.observed), len(self.inputs)
        self.feet = [self.model.geom(f"{side}_foot{i}_collision").id for side in ("left", "right") for i in range(1, 8)]
        self._state_size = mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_INTEGRATION)
        self._memory: OrderedDict[bytes, np.ndarray] = OrderedDict()
        self.memory = int(memory)
        self.ready = False
        self.fallen = self.last_clipped = False
        self.k = self.steps = self.falls = self.clipped_targets = 0

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

    # ---- state ----
    def state(self) -> np.ndarray:
        """The current 53-D state."""
        return legged_state(self.layout, self.data, self.observed)

    def is_fallen(self) -> bool:
        """Whether the robot is fallen now (``g1_model.FALL``)."""
        lay, d = self.layout, self.data
        return g.FALL.fallen(lay.quat(d), lay.height(d))

    def remember(self, x: np.ndarray) -> None:
        """Keeps the full physics state under the current state ``x`` for an exact ``reset(x0=x)``."""
        if self.memory <= 0:
            return
        buf = np.empty(self._state_size)
        self._mj.mj_getState(self.model, self.data, buf, self._mj.mjtState.mjSTATE_INTEGRATION)
        key = x.tobytes()
        self._memory[key] = buf
        self._memory.move_to_end(key)
        while len(self._memory) > self.memory:
            self._memory.popitem(last=False)

    def _start(self) -> np.ndarray:
        self.ready, self.fallen, self.k = True, self.is_fallen(), 0
        x = self.state()
        self.remember(x)
        return x

    def _full_targets(self, u: np.ndarray) -> np.ndarray:
        targets = self.default_pose.copy()
        targets[self.inputs] = u
        return targets

    # ---- reset ----
    def _lowest_foot(self, d: Any) -> float:
        """The lowest point (z) of the foot capsules."""
        m = self.model
        low = math.inf
        for f in self.feet:
            axis = np.asarray(d.geom_xmat[f]).reshape(3, 3)[:, 2] * m.geom_size[f][1]
            z = float(d.geom_xpos[f][2])
            low = min(low, z - abs(float(axis[2])) - float(m.geom_size[f][0]))
        return low

    def reset(self, seed: int | None = None, x0: npt.ArrayLike | None = None) -> np.ndarray:
        """Starts at ``x0`` (see the module docstring), else standing in the default pose with the
        lowest foot on the floor, at rest: with ``seed``, the input joints + U(±reset_range)
        (clipped to the limits) and a heading U(±π); without, exactly the default pose facing
        +x. Returns x_0."""
        mj, m, d, lay = self._mj, self.model, self.data, self.layout
        if x0 is not None:
            return self._reset_to(as_state(x0, self.nx, "x0"))
        q = self.default_pose.copy()
        yaw = 0.0
        if seed is not None:
            rng = np.random.default_rng(seed)
            yaw = float(rng.uniform(-math.pi, math.pi))
            i = self.inputs
            q[i] = np.clip(q[i] + rng.uniform(-self.reset_range, self.reset_range, len(i)), lay.q_min[i], lay.q_max[i])
        mj.mj_resetData(m, d)
        b = lay.base_qpos
        d.qpos[b : b + 3] = [0.0, 0.0, 1.0]
        d.qpos[b + 3 : b + 7] = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        d.qpos[lay.qpos] = q
        d.ctrl[lay.actuators] = q
        mj.mj_forward(m, d)
        d.qpos[b + 2] -= self._lowest_foot(d)
        mj.mj_forward(m, d)
        return self._start()

    def _reset_to(self, x: np.ndarray) -> np.ndarray:
        mj, m, d, lay = self._mj, self.model, self.data, self.layout
        n = len(self.observed)
        saved = self._memory.get(x.tobytes())
        if saved is not None:
            mj.mj_resetData(m, d)
            mj.mj_setState(m, d, saved, mj.mjtState.mjSTATE_INTEGRATION)
            mj.mj_forward(m, d)
            return self._start()
        quat, v_body, w_body = x[0:4], x[4:7], x[7:10]
        q, qd, height = x[10 : 10 + n], x[10 + n : 10 + 2 * n], float(x[10 + 2 * n])
        norm = float(np.linalg.norm(quat))
        if abs(norm - 1.0) > 0.01:
            raise InvalidInput(f"x0: the base quaternion {quat.tolist()} has norm {norm:.6g}, expected 1")
        quat = quat / norm
        lo, hi = lay.q_min[self.observed], lay.q_max[self.observed]
        out = [i for i in range(n) if not lo[i] - JOINT_SLACK <= q[i] <= hi[i] + JOINT_SLACK]
        if out:
            i = out[0]
            raise InvalidInput(f"x0: {g.STATE_JOINTS[i]} = {q[i]:.6g} rad is outside its range [{lo[i]:.6g}, {hi[i]:.6g}] (+-{JOINT_SLACK})")
        if height <= 0:
            raise InvalidInput(f"x0: base height {height:.6g} m puts the base under the floor (z = 0)")
        # Checked on a scratch MjData first: a refused state leaves the episode as it was.
        probe = self._probe
        mj.mj_resetData(m, probe)
        b, v = lay.base_qpos, lay.base_dof
        full = self.default_pose.copy()
        full[self.observed] = q
        probe.qpos[b : b + 3] = [0.0, 0.0, height]
        probe.qpos[b + 3 : b + 7] = quat
        probe.qpos[lay.qpos] = full
        probe.qvel[v : v + 3] = quat_to_matrix(quat) @ v_body
        probe.qvel[v + 3 : v + 6] = w_body
        probe.qvel[lay.dofs[self.observed]] = qd
        probe.ctrl[lay.actuators] = full
        mj.mj_forward(m, probe)
        too_deep = []
        for c in range(probe.ncon):
            geoms = [int(gid) for gid in probe.contact.geom[c]]
            if 0 not in [int(m.geom_bodyid[gid]) for gid in geoms]:
                continue  # self-contact: not the floor
            allowed = MAX_FOOT_PENETRATION if any(gid in self.feet for gid in geoms) else MAX_PENETRATION
            if -float(probe.contact.dist[c]) > allowed:
                too_deep.append((-float(probe.contact.dist[c]), allowed, geoms))
        if too_deep:
            depth, allowed, geoms = max(too_deep, key=lambda t: t[0])
            names = [m.geom(gid).name or "world" for gid in geoms]
            raise InvalidInput(
                f"x0 puts the robot {depth:.3g} m into the floor (contact {names[0]}/{names[1]}; base height {height:.4g} m, "
                f"at most {allowed} m allowed)"
            )
        mj.mj_resetData(m, d)
        d.qpos[:] = probe.qpos
        d.qvel[:] = probe.qvel
        d.ctrl[:] = probe.ctrl
        mj.mj_forward(m, d)
        return self._start()

    # ---- stepping ----
    def step(self, u: npt.ArrayLike) -> np.ndarray:
        """Holds the 23 joint targets ``u`` (rad, clipped to the joint limits; the 6 held joints
        at the default pose) for one dt; returns the next state. Raises ``SimFailure`` if MuJoCo
        went unstable (reset to go on)."""
        if not self.ready:
            raise InvalidInput("G1: not reset yet (or reset needed after a failure)")
        targets, n = clip_targets(as_input(u, self.nu, "u"), self.u_lo, self.u_hi)
        self.clipped_targets += n
        self.last_clipped = n > 0
        x = self.advance(targets)
        self.remember(x)
        return x

    def advance(self, targets: np.ndarray) -> np.ndarray:
        """Applies the 23 ``targets`` (already within bounds) for one dt, unchecked; updates the
        fall status and counters; returns the state."""
        m, d, mj = self.model, self.data, self._mj
        warned = int(d.warning.number.sum())
        d.ctrl[self.layout.actuators] = self._full_targets(targets)
        for _ in range(self.substeps):
            mj.mj_step(m, d)
        finish_physics_step(self, mj, warned, "G1", "pelvis")
        return self.state()

    # ---- the expert ----
    def expert_reset(self) -> None:
        """Forgets the expert's last action and restarts its gait phase."""
        self.expert.reset()

    def expert_targets(self, command: np.ndarray) -> np.ndarray:
        """The expert's targets of the 23 input joints for the current state and ``command``
        (vx, vy, ωz); the expert observes all 29 joints (locked ones at the default pose, at rest)."""
        lay, d = self.layout, self.data
        v = lay.base_dof
        q, qd = self.policy_default.copy(), np.zeros(len(g.JOINTS))
        q[self.present], qd[self.present] = d.qpos[lay.qpos], d.qvel[lay.dofs]
        full = self.expert.act(np.array(d.qvel[v + 3 : v + 6]), projected_gravity(lay.quat(d)), command, q, qd)
        return full[self.present[self.inputs]]

    def push(self, dv_xy: np.ndarray) -> None:
        """Adds ``dv_xy`` (m/s) to the base's horizontal velocity (world frame)."""
        v = self.layout.base_dof
        self.data.qvel[v : v + 2] += np.asarray(dv_xy, dtype=np.float64)

    def body_velocity(self) -> np.ndarray:
        """Base linear velocity in the body frame (m/s)."""
        lay, d = self.layout, self.data
        return body_from_world(lay.quat(d), d.qvel[lay.base_dof : lay.base_dof + 3])

    # ---- collection ----
    def expert_policy(self, d: dict[str, object]) -> ExpertPolicy:
        """The expert policy of JSON ``d`` with the G1's defaults (``EXPERT_DEFAULTS``) for the
        fields it leaves out."""
        return ExpertPolicy.from_json({**EXPERT_DEFAULTS, **d})

    def collect(self, policy: Policy, seed: int, n_windows: int, T: int, start: int = 0) -> Windows:
        """Windows ``start .. start + n_windows − 1`` in-process: ``expert`` / ``expert+noise``
        (``legged_collect``, the G1's command box unless given) or ``uniform`` targets within
        the bounds; ``planned`` is ``Unsupported``. Deterministic by the arguments, bit for bit.
        Afterwards the lockstep state is gone (reset first)."""
        try:
            if isinstance(policy, SimulatorPolicy):
                return collect_expert(self, self.expert_policy(policy.to_json()), seed, n_windows, T, start)
            if isinstance(policy, ExpertPolicy):
                return collect_expert(self, policy, seed, n_windows, T, start)
            if isinstance(policy, PlannedPolicy):
                raise Unsupported("the G1 has no planner: use the 'expert', 'expert+noise' or 'uniform' collect policy")
            if isinstance(policy, UniformPolicy):
                lo, hi = policy.bounds(self.info())
                if np.any(lo < self.u_lo) or np.any(hi > self.u_hi):
                    raise InvalidInput("uniform policy: the G1's targets must lie within its input bounds (u_min, u_max: the joint limits)")
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
        """The last ``step``'s flags for the step reply: ``terminated`` while fallen (``FALL``),
        ``clipped`` when its targets were clipped. Stepping goes on either way."""
        return {"terminated": self.fallen, "clipped": self.last_clipped}

    def close(self) -> None:
        """Prints the counters to standard error when there was a fall or a clipped target."""
        if self.falls or self.clipped_targets:
            print(f"G1: {self.counters()}", file=sys.stderr, flush=True)
        self.ready = False
