"""What every legged robot simulator here does the same way (the Go2, the G1): reset to the
default pose or to a state (checked on a scratch copy first, exact for states it returned),
stepping by clipped joint targets with fall detection, the expert and uniform collect policies,
counters and step flags. A robot supplies its model, actuation, feet and expert (``legged.go2.sim``,
``legged.g1.sim``)."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from ..._native import InvalidInput, KoopbridgeError, Unsupported
from ...collect import PlannedPolicy, Policy, SimulatorPolicy, UniformPolicy, Windows, collect_windows
from ...simulator import as_input, as_state
from ..state_memory import StateMemory
from .collect import ExpertPolicy, collect_expert
from .common import FallRule, LeggedLayout, body_from_world, clip_targets, finish_physics_step, legged_state, quat_to_matrix
from .perturbation import Perturbation, Perturber
from .policy import OnnxExpert

__all__ = ["JOINT_SLACK", "LeggedSimulator"]

#: How far (rad) a reset state's joint may be outside its range.
JOINT_SLACK = 0.2


class LeggedSimulator:
    """The shared body of a legged robot simulator. A subclass sets the class constants, calls
    ``_init_legged`` at the end of its ``__init__`` (after setting ``model``, ``data``,
    ``layout``, ``substeps``, ``dt``, ``expert``, ``default_pose`` (the layout's order),
    ``reset_joints`` and ``observed`` (layout indices drawn by a seeded reset / in the state),
    ``state_joints`` (their names) and ``feet`` (geom ids)), and implements ``info``,
    ``expert_targets``, ``_lowest_foot`` and ``_actuate`` (and, if it keeps actuation state
    outside MuJoCo, the ``_hold`` / ``_reset_actuation`` / ``_actuation_state`` /
    ``_restore_actuation`` hooks)."""

    #: The robot's name in messages, and its base body's.
    ROBOT: ClassVar[str]
    BASE_BODY: ClassVar[str]
    #: The body a perturbation's ``mass_scale`` scales (the Go2's trunk, the G1's torso).
    MASS_BODY: ClassVar[str]
    #: The fall thresholds.
    FALL: ClassVar[FallRule]
    #: The base height (m) a seeded reset places the robot at before lowering it onto its feet.
    START_HEIGHT: ClassVar[float]
    #: How far (m) a reset state may push a foot geom / any other robot geom into the floor.
    MAX_FOOT_PENETRATION: ClassVar[float]
    MAX_PENETRATION: ClassVar[float] = 0.02
    #: The error a bad constructor argument raises (the robot's model module's ``ModelError``).
    MODEL_ERROR: ClassVar[type[KoopbridgeError]]
    #: Defaults of the ``expert`` collect policy's fields (JSON) that differ from ``ExpertPolicy``'s.
    EXPERT_DEFAULTS: ClassVar[dict[str, object]] = {}

    model: Any
    data: Any
    layout: LeggedLayout
    substeps: int
    dt: float
    expert: OnnxExpert
    default_pose: np.ndarray
    reset_joints: np.ndarray
    observed: np.ndarray
    state_joints: list[str]
    feet: list[int]

    def _init_legged(
        self,
        mujoco: Any,
        *,
        q_lo: np.ndarray,
        q_hi: np.ndarray,
        target_margin: float,
        reset_range: float,
        memory: int,
        env: str,
        on_fall: Callable[[str], None] | None,
    ) -> None:
        """The shared part of the constructor: the input bounds ``u_lo``, ``u_hi`` (the input
        joints' ranges ``q_lo``, ``q_hi`` widened by ``target_margin``), the counters, the
        exact-restore memory and a scratch ``MjData`` for checking reset states."""
        if not (math.isfinite(target_margin) and target_margin >= 0):
            raise self.MODEL_ERROR(f"target margin must be finite and >= 0, got {target_margin}")
        self._mj = mujoco
        self._probe = mujoco.MjData(self.model)
        self.target_margin = float(target_margin)
        self.u_lo, self.u_hi = q_lo - self.target_margin, q_hi + self.target_margin
        self.nu = len(q_lo)
        self.reset_range = float(reset_range)
        self.env = env
        self.on_fall = on_fall
        self.nx = 11 + 2 * len(self.observed)
        self.memory = int(memory)
        self._states = StateMemory(mujoco, self.model, self.memory)
        self.ready = False
        self.fallen = self.last_clipped = False
        self.k = self.steps = self.falls = self.clipped_targets = 0
        self._perturber = Perturber(self.model, self._body_id(self.MASS_BODY), self.feet)

    def _body_id(self, name: str) -> int:
        """The id of body ``name`` (or of the one named ``{prefix}/{name}``)."""
        m = self.model
        for b in range(m.nbody):
            if m.body(b).name == name or m.body(b).name.endswith("/" + name):
                return b
        raise self.MODEL_ERROR(f"the {self.ROBOT} model has no body {name!r}")

    # ---- robot-specific hooks ----
    def _lowest_foot(self, d: Any) -> float:
        """The lowest point (z, m) of the feet in ``d``."""
        raise NotImplementedError

    def _actuate(self, targets: np.ndarray) -> None:
        """Holds the (already clipped) input ``targets`` over ``substeps`` physics steps."""
        raise NotImplementedError

    def _hold(self, d: Any, q: np.ndarray) -> None:
        """Before a reset's first ``mj_forward``: sets whatever holds the joints at ``q`` (the
        layout's order) in ``d`` (position servos' ``ctrl``); default nothing."""

    def _reset_actuation(self) -> None:
        """After a reset to a new state: clears actuation state kept outside MuJoCo."""

    def _actuation_state(self) -> Any:
        """A copy of the actuation state kept outside MuJoCo, for the exact-restore memory."""
        return None

    def _restore_actuation(self, saved: Any) -> None:
        """Restores what ``_actuation_state`` returned."""

    # ---- state ----
    def state(self) -> np.ndarray:
        """The current trimmed state (``legged.legged_state`` over ``observed``)."""
        return legged_state(self.layout, self.data, self.observed)

    def is_fallen(self) -> bool:
        """Whether the robot is fallen now (``FALL``)."""
        lay, d = self.layout, self.data
        return self.FALL.fallen(lay.quat(d), lay.height(d))

    def remember(self, x: np.ndarray) -> None:
        """Keeps the full physics state (base x/y, unobserved joints, actuation, solver warm
        start) under the current state ``x``, for an exact ``reset(x0=x)`` later (the last
        ``memory`` ones)."""
        self._states.remember(x, self.data, self._actuation_state())

    def _start(self) -> np.ndarray:
        self.ready, self.fallen, self.k = True, self.is_fallen(), 0
        x = self.state()
        self.remember(x)
        return x

    # ---- reset ----
    def reset(self, seed: int | None = None, x0: npt.ArrayLike | None = None, perturbation: dict[str, Any] | None = None) -> np.ndarray:
        """Starts at ``x0`` (see the robot's module docstring), else standing in the default pose
        with the lowest foot on the floor, at rest: with ``seed``, the ``reset_joints`` + U(±
        reset_range) (clipped to their limits) and a heading U(±π); without, exactly the default
        pose facing +x. ``perturbation`` (``legged.perturbation``: ``mass_scale``,
        ``friction_scale``, ``push``) holds for this episode; without it the robot is nominal.
        Returns x_0."""
        mj, m, d, lay = self._mj, self.model, self.data, self.layout
        self._perturber.apply(Perturbation.from_json(perturbation))
        if x0 is not None:
            return self._reset_to(as_state(x0, self.nx, "x0"))
        q = self.default_pose.copy()
        yaw = 0.0
        if seed is not None:
            rng = np.random.default_rng(seed)
            yaw = float(rng.uniform(-math.pi, math.pi))
            i = self.reset_joints
            q[i] = np.clip(q[i] + rng.uniform(-self.reset_range, self.reset_range, len(i)), lay.q_min[i], lay.q_max[i])
        mj.mj_resetData(m, d)
        b = lay.base_qpos
        d.qpos[b : b + 3] = [0.0, 0.0, self.START_HEIGHT]
        d.qpos[b + 3 : b + 7] = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        d.qpos[lay.qpos] = q
        self._hold(d, q)
        mj.mj_forward(m, d)
        d.qpos[b + 2] -= self._lowest_foot(d)
        mj.mj_forward(m, d)
        self._reset_actuation()
        return self._start()

    def _reset_to(self, x: np.ndarray) -> np.ndarray:
        mj, m, d, lay = self._mj, self.model, self.data, self.layout
        saved = self._states.lookup(x)
        if saved is not None:
            mj.mj_resetData(m, d)
            self._restore_actuation(self._states.apply(saved, d))
            return self._start()
        n = len(self.observed)
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
            raise InvalidInput(f"x0: {self.state_joints[i]} = {q[i]:.6g} rad is outside its range [{lo[i]:.6g}, {hi[i]:.6g}] (+-{JOINT_SLACK})")
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
        self._hold(probe, full)
        mj.mj_forward(m, probe)
        self._check_floor_contacts(probe, height)
        mj.mj_resetData(m, d)
        d.qpos[:] = probe.qpos
        d.qvel[:] = probe.qvel
        d.ctrl[:] = probe.ctrl
        mj.mj_forward(m, d)
        self._reset_actuation()
        return self._start()

    def _check_floor_contacts(self, probe: Any, height: float) -> None:
        """Refuses a state whose robot geoms go deeper into the floor than allowed (self-contacts
        are not the floor's business)."""
        m = self.model
        too_deep = []  # (depth, allowed, geoms) of every floor contact deeper than allowed
        for c in range(probe.ncon):
            geoms = [int(gid) for gid in probe.contact.geom[c]]
            if 0 not in [int(m.geom_bodyid[gid]) for gid in geoms]:
                continue
            allowed = self.MAX_FOOT_PENETRATION if any(gid in self.feet for gid in geoms) else self.MAX_PENETRATION
            if -float(probe.contact.dist[c]) > allowed:
                too_deep.append((-float(probe.contact.dist[c]), allowed, geoms))
        if too_deep:
            depth, allowed, geoms = max(too_deep, key=lambda t: t[0])
            names = [m.geom(gid).name or m.body(int(m.geom_bodyid[gid])).name or "world" for gid in geoms]
            raise InvalidInput(
                f"x0 puts the robot {depth:.3g} m into the floor (contact {names[0]}/{names[1]}; base height {height:.4g} m, "
                f"at most {allowed} m allowed)"
            )

    # ---- stepping ----
    def step(self, u: npt.ArrayLike) -> np.ndarray:
        """Holds the joint targets ``u`` (rad, clipped to the input bounds) for one dt; returns
        the next state. Raises ``SimFailure`` if MuJoCo went unstable (reset to go on)."""
        if not self.ready:
            raise InvalidInput(f"{self.ROBOT}: not reset yet (or reset needed after a failure)")
        targets, n = clip_targets(as_input(u, self.nu, "u"), self.u_lo, self.u_hi)
        self.clipped_targets += n
        self.last_clipped = n > 0
        dv = self._perturber.push_now(self.k)
        if dv is not None:
            self.push(np.asarray(dv))
        x = self.advance(targets)
        self.remember(x)
        return x

    def advance(self, targets: np.ndarray) -> np.ndarray:
        """Applies ``targets`` (already within bounds) for one dt, unchecked; updates the fall
        status and counters; returns the state."""
        warned = int(self.data.warning.number.sum())
        self._actuate(targets)
        finish_physics_step(self, self._mj, warned, self.ROBOT, self.BASE_BODY)
        return self.state()

    # ---- the expert ----
    def expert_reset(self) -> None:
        """Forgets the expert's last action (and restarts its gait phase, if it has one)."""
        self.expert.reset()

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
        """The expert policy of JSON ``d`` with this robot's defaults (``EXPERT_DEFAULTS``) for
        the fields it leaves out."""
        return ExpertPolicy.from_json({**self.EXPERT_DEFAULTS, **d})

    def collect(self, policy: Policy, seed: int, n_windows: int, T: int, start: int = 0) -> Windows:
        """Windows ``start .. start + n_windows − 1`` in-process: ``expert`` / ``expert+noise``
        (``legged.collect``) or ``uniform`` targets within the input bounds (one per step,
        ``koopbridge.collect``); ``planned`` is ``Unsupported``. The same arguments give the
        same arrays, bit for bit. Afterwards the lockstep state is gone (reset first)."""
        try:
            if isinstance(policy, SimulatorPolicy):
                return collect_expert(self, self.expert_policy(policy.to_json()), seed, n_windows, T, start)
            if isinstance(policy, ExpertPolicy):
                return collect_expert(self, policy, seed, n_windows, T, start)
            if isinstance(policy, PlannedPolicy):
                raise Unsupported(f"the {self.ROBOT} has no planner: use the 'expert', 'expert+noise' or 'uniform' collect policy")
            if isinstance(policy, UniformPolicy):
                lo, hi = policy.bounds(self.info())  # type: ignore[attr-defined]
                if np.any(lo < self.u_lo) or np.any(hi > self.u_hi):
                    raise InvalidInput(f"uniform policy: the {self.ROBOT}'s targets must lie within its input bounds (u_min, u_max: the joint limits)")
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
        that step's targets were clipped to the input bounds. Stepping goes on either way."""
        return {"terminated": self.fallen, "clipped": self.last_clipped}

    def close(self) -> None:
        """Prints the counters to standard error when there was a fall or a clipped target."""
        if self.falls or self.clipped_targets:
            print(f"{self.ROBOT}: {self.counters()}", file=sys.stderr, flush=True)
        self.ready = False
