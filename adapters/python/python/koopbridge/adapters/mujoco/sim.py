"""The Franka Panda in MuJoCo as a discrete-time ``koopbridge.Simulator``: joint-velocity
commands (clipped to ±0.3 rad/s, held over dt = 10 × 0.002 s) tracked by velocity servos with
gravity compensation; state ``[ee position (3), q (7), qd (7)]`` or ``[q, qd]``; SPEC's seeded
reset around home. No networking here (see ``mujoco.__main__``)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from ..._native import InvalidInput, KoopbridgeError
from ...collect import Policy, Windows, collect_windows
from ...simulator import SimInfo, as_input, as_state
from .model import HOME, JOINTS, PandaModel, PandaOptions, build_panda

__all__ = ["FrankaSimulator", "SimFailure", "STATES"]

#: The state layouts ``--state`` accepts.
STATES = ("ee,q,qd", "q,qd")


class SimFailure(KoopbridgeError):
    """MuJoCo became unstable (a non-finite state or a bad-acceleration warning); reset to go on."""


class FrankaSimulator:
    """One Franka Panda in MuJoCo, stepped by joint-velocity commands.

    ``model``: an MJCF file (default: robosuite's Panda, see ``mujoco.model``); ``state``:
    ``"ee,q,qd"`` (17-D, SPEC) or ``"q,qd"`` (14-D); ``options``: actuation and timing
    (``PandaOptions``); ``reset_range``: half-width of the uniform draw around ``HOME`` of a
    seeded reset (SPEC: 0.2 rad, then clipped to the joint limits); ``env``: reported name.

    ``reset(x0=...)`` takes a full state; its end-effector part is ignored (it follows from
    ``q``), ``q`` outside the joint limits is refused. ``step(u)`` clips ``u`` to ±``u_limit``.
    """

    def __init__(
        self,
        model: str | None = None,
        *,
        state: str = "ee,q,qd",
        options: PandaOptions | None = None,
        reset_range: float = 0.2,
        env: str = "franka-panda",
    ) -> None:
        import mujoco

        if state not in STATES:
            raise KoopbridgeError(f"state layout '{state}': expected one of {', '.join(STATES)}")
        self._mj = mujoco
        self.arm: PandaModel = build_panda(model, options)
        self.model = self.arm.model
        self.data = mujoco.MjData(self.model)
        self.options = self.arm.options
        self.state_layout = state
        self.with_ee = state == "ee,q,qd"
        self.reset_range = float(reset_range)
        self.env = env
        self.q_lo = np.array([r[0] for r in self.arm.joint_range])
        self.q_hi = np.array([r[1] for r in self.arm.joint_range])
        self.qadr = np.array(self.arm.qpos_adr)
        self.vadr = np.array(self.arm.dof_adr)
        self.home = np.clip(np.array(HOME), self.q_lo, self.q_hi)
        self.ready = False
        self.k = 0

    # ---- description ----
    @property
    def nx(self) -> int:
        """State dimension (17 or 14)."""
        return 17 if self.with_ee else 14

    def state_names(self) -> list[str]:
        """``ee_x, ee_y, ee_z`` (if in the state), ``q1..q7``, ``qd1..qd7``."""
        ee = ["ee_x", "ee_y", "ee_z"] if self.with_ee else []
        return ee + [f"q{i}" for i in range(1, 8)] + [f"qd{i}" for i in range(1, 8)]

    def info(self) -> SimInfo:
        """Names, units, bounds, dt, the MuJoCo version and the actuation, as a ``SimInfo``."""
        o = self.options
        ee_units = ["m"] * 3 if self.with_ee else []
        qd_max = [o.u_limit] * 7
        return SimInfo(
            env=self.env,
            kind="mujoco",
            version=f"MuJoCo {self._mj.__version__}",
            dt=o.dt,
            state_names=self.state_names(),
            input_names=[f"qd{i}_cmd" for i in range(1, 8)],
            u_min=[-o.u_limit] * 7,
            u_max=[o.u_limit] * 7,
            extra=dict(
                mujoco=dict(
                    version=self._mj.__version__,
                    model_file=self.arm.path,
                    joints=list(JOINTS),
                    units=dict(state=ee_units + ["rad"] * 7 + ["rad/s"] * 7, input=["rad/s"] * 7),
                    state_bounds=dict(
                        low=[None] * len(ee_units) + self.q_lo.tolist() + [-v for v in qd_max],
                        high=[None] * len(ee_units) + self.q_hi.tolist() + qd_max,
                    ),
                    actuation=dict(
                        servo="velocity",
                        kv=o.kv,
                        force_range=[list(r) for r in self.arm.force_range],
                        gravcomp=o.gravcomp,
                        command_clip=o.u_limit,
                    ),
                    timestep=o.timestep,
                    substeps=o.substeps,
                    integrator="implicitfast",
                    home=self.home.tolist(),
                    reset_range=self.reset_range,
                    x0="the end-effector part of x0 is ignored: it follows from q",
                )
            ),
        )

    # ---- simulation ----
    def state(self) -> np.ndarray:
        """The current state vector."""
        d = self.data
        parts = [d.qpos[self.qadr], d.qvel[self.vadr]]
        if self.with_ee:
            parts.insert(0, d.site_xpos[self.arm.ee_site])
        return np.concatenate(parts)

    def ee_position(self, q: npt.ArrayLike | None = None) -> np.ndarray:
        """The end-effector position at joint angles ``q`` (default: the current ones)."""
        if q is None:
            return self.data.site_xpos[self.arm.ee_site].copy()
        d = self._mj.MjData(self.model)
        d.qpos[self.qadr] = as_input(q, 7, "q")
        self._mj.mj_kinematics(self.model, d)
        return d.site_xpos[self.arm.ee_site].copy()

    def initial_q(self, seed: int | None) -> np.ndarray:
        """SPEC's initial joint angles: home + U(±reset_range) by ``seed`` clipped to the joint
        limits; home itself when ``seed`` is None."""
        if seed is None:
            return self.home.copy()
        rng = np.random.default_rng(seed)
        return np.clip(self.home + rng.uniform(-self.reset_range, self.reset_range, 7), self.q_lo, self.q_hi)

    def reset(self, seed: int | None = None, x0: npt.ArrayLike | None = None) -> np.ndarray:
        """Starts at ``x0`` (its q and qd), else at ``initial_q(seed)`` at rest; returns x_0."""
        if x0 is not None:
            x = as_state(x0, self.nx, "x0")
            off = 3 if self.with_ee else 0
            q, qd = x[off : off + 7], x[off + 7 : off + 14]
            bad = [i for i in range(7) if not self.q_lo[i] <= q[i] <= self.q_hi[i]]
            if bad:
                i = bad[0]
                raise InvalidInput(
                    f"x0: {JOINTS[i]} = {q[i]:.6g} rad is outside its limits [{self.q_lo[i]:.6g}, {self.q_hi[i]:.6g}]"
                )
        else:
            q, qd = self.initial_q(seed), np.zeros(7)
        m, d = self.model, self.data
        self._mj.mj_resetData(m, d)
        d.qpos[self.qadr] = q
        d.qvel[self.vadr] = qd
        self._mj.mj_forward(m, d)
        self.ready = True
        self.k = 0
        return self.state()

    def step(self, u: npt.ArrayLike) -> np.ndarray:
        """Applies the velocity command ``u`` (clipped to ±u_limit) for ``substeps`` physics
        steps; returns the next state. Raises ``SimFailure`` if MuJoCo went unstable."""
        if not self.ready:
            raise InvalidInput("MuJoCo Panda: not reset yet (or reset needed after a failure)")
        u = as_input(u, 7, "u")
        self._advance(np.clip(u, -self.options.u_limit, self.options.u_limit))
        return self.state()

    def _advance(self, u: np.ndarray) -> None:
        m, d, mj = self.model, self.data, self._mj
        warned = int(d.warning.number.sum())
        d.ctrl[:] = u
        mj.mj_step(m, d, nstep=self.options.substeps)
        # mj_step leaves the kinematics of the state before its last integration: bring the
        # end-effector site up to date with the new q.
        mj.mj_kinematics(m, d)
        # MuJoCo itself resets the data after a NaN or a huge value in qpos/qvel/qacc and counts a
        # warning; the sum also catches a non-finite value it let through.
        if int(d.warning.number.sum()) != warned or not math.isfinite(d.qpos.sum() + d.qvel.sum()):
            self.ready = False
            names = [mj.mjtWarning(i).name for i, n in enumerate(d.warning.number) if n]
            raise SimFailure(
                f"MuJoCo Panda: unstable at step {self.k} (t = {self.k * self.options.dt:.4g} s; warnings {names or 'none'}, "
                "non-finite or reset state); reset to go on"
            )
        self.k += 1

    def collect(self, policy: Policy, seed: int, n_windows: int, T: int, start: int = 0) -> Windows:
        """``n_windows`` windows of ``T`` steps in-process (``koopbridge.collect``): window
        ``start + i`` resets with its own seed and applies ``policy``'s commands; the same
        arguments give the same arrays, bit for bit, and equal the lockstep path."""
        return collect_windows(self, policy, seed, n_windows, T, start=start, step=self._fast_step)

    def _fast_step(self, u: np.ndarray) -> np.ndarray:
        # `collect_windows` has checked u already; MuJoCo clamps ctrl to the servos' ±u_limit
        # control range exactly as np.clip does in `step`, so both paths give the same states.
        self._advance(u)
        return self.state()

    def close(self) -> None:
        """Nothing to free (the model and data are garbage-collected)."""
        self.ready = False

