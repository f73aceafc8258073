"""Any Gymnasium environment with a Box action space as a discrete-time ``koopbridge.Simulator``:
inputs are the action's components (bounds from the Box), ``dt`` is the environment's, the state
is the full MuJoCo state ``[qpos, qvel(, act)]`` for MuJoCo-based environments or the
observation; episode ends are reported, never acted on. No networking here (see ``gym.__main__``).

``reset(x0=x)`` (state ``qpos,qvel``) resets the environment (a new episode for its wrappers, the
time limit included) and then sets the MuJoCo state: a state this simulator returned, among its
last ``memory`` ones, is restored with everything MuJoCo integrates (the solver's warm start,
time, activations: stepping on is then bit for bit the original run, contacts included); any
other is set with the environment's own ``set_state`` (warm start and time fresh, as after
``env.reset``). With the state ``obs`` it is possible only when the observation is exactly
``[qpos, qvel]`` (InvertedPendulum); otherwise it is ``Unsupported``.
"""

from __future__ import annotations

import difflib
import math
import sys
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from ..._native import InvalidInput, KoopbridgeError, Unsupported
from ...simulator import SimInfo, as_input, as_state
from ..state_memory import StateMemory

__all__ = ["GymError", "GymSimulator", "SimFailure", "STATES", "close_env_ids", "mujoco_state_names"]

#: The state layouts ``--state`` accepts (``auto``: ``qpos,qvel`` for MuJoCo environments, else ``obs``).
STATES = ("auto", "qpos,qvel", "obs")


class GymError(KoopbridgeError):
    """The environment cannot be served as asked (unknown id, non-Box actions, bad options)."""


class SimFailure(KoopbridgeError):
    """The environment returned a non-finite state; reset to go on."""


def close_env_ids(env_id: str, n: int = 5) -> list[str]:
    """Up to ``n`` registered Gymnasium environment ids closest to ``env_id`` (``difflib``)."""
    import gymnasium

    ids = sorted(gymnasium.registry.keys())
    close = difflib.get_close_matches(env_id, ids, n=n, cutoff=0.5)
    if not close:  # e.g. "InvertedPendulum" without a version: ids sharing the name
        base = env_id.split("-v")[0].lower()
        close = [i for i in ids if base and base in i.lower()][:n]
    return close


def mujoco_state_names(model: Any) -> tuple[list[str], list[str], list[int]]:
    """Names of the ``qpos`` and ``qvel`` components from the model's joints, and which ``qpos``
    components are hinge angles. A hinge or slide joint ``j`` gives ``j`` and ``j_vel``; a ball
    joint ``j_qw..j_qz`` and ``j_wx..j_wz``; a free joint its position, quaternion and linear and
    angular velocity; an unnamed joint is called ``joint<i>``."""
    import mujoco

    jt = mujoco.mjtJoint
    qpos: list[str] = [""] * model.nq
    qvel: list[str] = [""] * model.nv
    angles: list[int] = []
    for j in range(model.njnt):
        name = model.joint(j).name or f"joint{j}"
        kind, qa, va = int(model.jnt_type[j]), int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])
        if kind == jt.mjJNT_FREE:
            p = [f"{name}_{s}" for s in ("x", "y", "z", "qw", "qx", "qy", "qz")]
            v = [f"{name}_{s}" for s in ("vx", "vy", "vz", "wx", "wy", "wz")]
        elif kind == jt.mjJNT_BALL:
            p = [f"{name}_{s}" for s in ("qw", "qx", "qy", "qz")]
            v = [f"{name}_{s}" for s in ("wx", "wy", "wz")]
        else:
            p, v = [name], [f"{name}_vel"]
            if kind == jt.mjJNT_HINGE:
                angles.append(qa)
        qpos[qa : qa + len(p)] = p
        qvel[va : va + len(v)] = v
    qpos = [n or f"qpos{i}" for i, n in enumerate(qpos)]
    qvel = [n or f"qvel{i}" for i, n in enumerate(qvel)]
    return qpos, qvel, angles


def _make(env_id: str, make_kwargs: Mapping[str, Any]) -> Any:
    import gymnasium
    from gymnasium import error

    try:
        return gymnasium.make(env_id, **make_kwargs)
    except (error.NameNotFound, error.NamespaceNotFound, error.VersionNotFound, error.DeprecatedEnv, error.UnregisteredEnv) as e:
        close = close_env_ids(env_id)
        hint = f"; close names: {', '.join(close)}" if close else ""
        raise GymError(f"Gymnasium environment '{env_id}' does not exist ({e}){hint}") from e
    except error.DependencyNotInstalled as e:
        raise GymError(f"Gymnasium environment '{env_id}' needs a package that is not installed: {e}") from e
    except (TypeError, ValueError, error.Error) as e:
        raise GymError(f"Gymnasium environment '{env_id}' could not be made with {dict(make_kwargs)}: {e}") from e


class GymSimulator:
    """One Gymnasium environment, stepped by its (Box) actions.

    ``env_id``: a registered id (``InvertedPendulum-v5``); ``state``: ``auto``, ``qpos,qvel``
    (MuJoCo environments only) or ``obs``; ``dt``: seconds per step for an environment that has
    no ``dt`` of its own (refused when it differs from the environment's); ``make_kwargs``:
    passed to ``gymnasium.make`` (``max_episode_steps``, ``reset_noise_scale``, ...);
    ``on_episode_end``: called with a message when an episode terminates or is truncated;
    ``memory``: how many returned states ``reset(x0=)`` restores with MuJoCo's whole integration
    state (module docstring).

    Actions outside the Box are clipped to it (counted); an integer Box gets rounded actions.
    A step after termination or truncation steps the environment on, as it is; the episode
    restarts only at the next ``reset``. ``status()`` holds the last step's ``terminated``,
    ``truncated`` and ``reward`` and the counters; ``step_status()`` gives the step reply its
    ``terminated``, ``truncated`` and ``clipped`` flags.
    """

    def __init__(
        self,
        env_id: str,
        *,
        state: str = "auto",
        dt: float | None = None,
        make_kwargs: Mapping[str, Any] | None = None,
        on_episode_end: Callable[[str], None] | None = None,
        memory: int = 4096,
    ) -> None:
        import gymnasium
        from gymnasium import spaces

        if state not in STATES:
            raise GymError(f"state layout '{state}': expected one of {', '.join(STATES)}")
        self._gym = gymnasium
        self.env_id = env_id
        self.make_kwargs = dict(make_kwargs or {})
        self.env = _make(env_id, self.make_kwargs)
        self.raw = self.env.unwrapped
        a = self.env.action_space
        if not isinstance(a, spaces.Box):
            self.env.close()
            raise GymError(f"{env_id}: the action space is {a}, not a Box: this adapter serves continuous (Box) actions only")
        self.action_space = a
        self.mujoco = self._mujoco_model()
        if state == "auto":
            state = "qpos,qvel" if self.mujoco is not None else "obs"
        if state == "qpos,qvel" and self.mujoco is None:
            self.env.close()
            raise GymError(f"{env_id} is not MuJoCo-based (its unwrapped env has no MuJoCo model and data): use --state obs")
        self.layout = state
        o = self.env.observation_space
        if state == "obs" and not (isinstance(o, spaces.Box) and np.issubdtype(o.dtype, np.number)):
            self.env.close()
            raise GymError(f"{env_id}: the observation space is {o}, not a numeric Box: it cannot be the state")
        self.dt = self._dt(dt)
        self.on_episode_end = on_episode_end
        self.nu = int(np.prod(a.shape))
        self.u_lo = np.asarray(a.low, dtype=np.float64).ravel()
        self.u_hi = np.asarray(a.high, dtype=np.float64).ravel()
        self.obs_is_state = False
        if self.mujoco is not None:
            m = self.mujoco
            obs, _ = self.env.reset(seed=0)
            self.obs_is_state = np.shape(obs) == (m.nq + m.nv,) and np.array_equal(np.asarray(obs, dtype=np.float64), self._mujoco_state()[: m.nq + m.nv])
        self.nx = self._nx()
        self.full_state = self.mujoco is not None and (self.layout == "qpos,qvel" or self.obs_is_state)
        self.memory = int(memory)
        self._states: StateMemory | None = None
        if self.mujoco is not None:
            import mujoco

            self._states = StateMemory(mujoco, self.mujoco, self.memory)
        self.ready = False
        self.terminated = self.truncated = self.last_clipped = False
        self.reward = 0.0
        self.k = self.steps = self.episodes = self.terminations = self.truncations = self.clipped_inputs = 0

    def _mujoco_model(self) -> Any:
        raw = self.raw
        if not all(hasattr(raw, n) for n in ("model", "data", "set_state")):
            return None
        try:
            import mujoco
        except ImportError:
            return None
        return raw.model if isinstance(raw.model, mujoco.MjModel) and isinstance(raw.data, mujoco.MjData) else None

    def _dt(self, dt: float | None) -> float:
        own = getattr(self.raw, "dt", None)
        if own is not None and not (isinstance(own, (int, float)) and math.isfinite(own) and own > 0):
            own = None
        if dt is not None:
            if not (math.isfinite(dt) and dt > 0):
                raise GymError(f"--dt must be a positive number of seconds, got {dt}")
            if own is not None and not math.isclose(dt, own, rel_tol=1e-9):
                raise GymError(f"{self.env_id} steps dt = {own} s; --dt {dt} cannot change that (leave --dt out)")
            return float(dt)
        if own is None:
            raise GymError(f"{self.env_id} does not say its time step (no env.unwrapped.dt): give --dt SECONDS")
        return float(own)

    def _nx(self) -> int:
        if self.layout == "obs":
            return int(np.prod(self.env.observation_space.shape))
        m = self.mujoco
        return m.nq + m.nv + m.na

    # ---- description ----
    def state_names(self) -> list[str]:
        """``qpos`` then ``qvel`` names from the joints (``mujoco_state_names``), then ``act<i>``;
        or ``obs0, obs1, ...`` (the observation's names when it is exactly ``[qpos, qvel]``)."""
        if self.full_state:
            qpos, qvel, _ = mujoco_state_names(self.mujoco)
            act = [f"act{i}" for i in range(self.mujoco.na)] if self.layout == "qpos,qvel" else []
            return qpos + qvel + act
        return [f"obs{i}" for i in range(self.nx)]

    def input_names(self) -> list[str]:
        """For a MuJoCo environment whose action is its controls: each actuator's name, else
        ``<joint>_cmd`` for one that drives a joint; otherwise (or when names repeat) ``a0, a1, ...``."""
        plain = [f"a{i}" for i in range(self.nu)]
        m = self.mujoco
        if m is None or m.nu != self.nu:
            return plain
        import mujoco

        names = []
        for i in range(m.nu):
            name = m.actuator(i).name
            if not name and int(m.actuator_trntype[i]) == mujoco.mjtTrn.mjTRN_JOINT:
                name = f"{m.joint(int(m.actuator_trnid[i][0])).name or 'joint'}_cmd"
            names.append(name or f"a{i}")
        return names if len(set(names)) == len(names) else plain

    def info(self) -> SimInfo:
        """Names, bounds (the action Box), dt, the Gymnasium and MuJoCo versions and how episodes,
        resets and clipping behave, as a ``SimInfo``."""
        env = self.env
        angles: list[int] = []
        if self.full_state:
            angles = mujoco_state_names(self.mujoco)[2]
        spec = env.spec
        g: dict[str, Any] = dict(
            version=self._gym.__version__,
            env_id=self.env_id,
            make_kwargs={k: v for k, v in self.make_kwargs.items()},
            state=self.layout,
            action_space=str(env.action_space),
            observation_space=str(env.observation_space),
            max_episode_steps=spec.max_episode_steps if spec is not None else None,
            episodes="termination and truncation are reported (stderr, the step reply's status) and never stop the adapter: a step after "
            "them steps the environment on; reset starts a new episode",
            actions="clipped to the action Box (counted, flagged 'clipped' in the step reply)",
            seeded_reset="env.reset(seed=seed)",
        )
        if self.mujoco is not None:
            import mujoco

            m = self.mujoco
            g["mujoco"] = dict(
                version=mujoco.__version__, nq=m.nq, nv=m.nv, na=m.na, timestep=float(m.opt.timestep), frame_skip=getattr(self.raw, "frame_skip", None)
            )
            g["observation_is_state"] = self.obs_is_state
        if self.full_state:
            g["x0"] = (
                f"env.reset(), then a state among the last {self.memory} returned is restored with MuJoCo's whole integration state "
                "(warm start, time: bit for bit); any other is set by set_state(qpos, qvel) (warm start and time fresh)"
            )
        else:
            g["x0"] = "unsupported: the observation does not determine the environment's state"
        return SimInfo(
            env=self.env_id,
            kind="gymnasium",
            version=f"Gymnasium {self._gym.__version__}",
            dt=self.dt,
            state_names=self.state_names(),
            input_names=self.input_names(),
            u_min=self.u_lo.tolist(),
            u_max=self.u_hi.tolist(),
            angle_indices=angles,
            extra=dict(gymnasium=g),
        )

    # ---- state ----
    def _mujoco_state(self) -> np.ndarray:
        d = self.raw.data
        return np.concatenate([d.qpos, d.qvel, d.act]).astype(np.float64)

    def _state(self, obs: Any) -> np.ndarray:
        x = self._mujoco_state() if self.layout == "qpos,qvel" else np.asarray(obs, dtype=np.float64).ravel()
        if x.shape != (self.nx,) or not np.all(np.isfinite(x)):
            self.ready = False
            raise SimFailure(f"{self.env_id}: non-finite or misshapen state at step {self.k} ({x.shape}, expected ({self.nx},)); reset to go on")
        if self.full_state and self.memory > 0:
            self._remember(x)
        return x

    def _remember(self, x: np.ndarray) -> None:
        if self._states is not None:
            self._states.remember(x, self.raw.data)

    def _start(self, obs: Any) -> np.ndarray:
        self.ready, self.terminated, self.truncated, self.reward, self.k = True, False, False, 0.0, 0
        self.episodes += 1
        return self._state(obs)

    # ---- reset ----
    def reset(self, seed: int | None = None, x0: npt.ArrayLike | None = None) -> np.ndarray:
        """Starts a new episode: at ``x0`` (see the module docstring), else ``env.reset(seed=seed)``
        (without a seed: the environment's random generator goes on). Returns x_0."""
        if x0 is not None:
            return self._reset_to(as_state(x0, self.nx, "x0"))
        obs, _ = self.env.reset(seed=None if seed is None else int(seed))
        return self._start(obs)

    def _reset_to(self, x: np.ndarray) -> np.ndarray:
        if self.mujoco is None or not self.full_state:
            why = "it is not MuJoCo-based" if self.mujoco is None else "the observation is not [qpos, qvel] (use --state qpos,qvel)"
            raise Unsupported(f"{self.env_id}: reset(x0) needs the full state, and with --state obs {why}")
        import mujoco

        m = self.mujoco
        qpos, qvel, act = x[: m.nq], x[m.nq : m.nq + m.nv], x[m.nq + m.nv :]
        for j in range(m.njnt):
            kind, a = int(m.jnt_type[j]), int(m.jnt_qposadr[j])
            name = m.joint(j).name or f"joint{j}"
            if kind in (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL):
                qa = a + 3 if kind == mujoco.mjtJoint.mjJNT_FREE else a
                norm = float(np.linalg.norm(qpos[qa : qa + 4]))
                if abs(norm - 1.0) > 0.01:
                    raise InvalidInput(f"x0: the quaternion of joint {name} has norm {norm:.6g}, expected 1")
        self.env.reset()
        saved = self._states.lookup(x) if self._states is not None else None
        if saved is not None and self._states is not None:
            self._states.apply(saved, self.raw.data)
        else:
            self.raw.set_state(qpos, qvel)
            if m.na and self.layout == "qpos,qvel":
                self.raw.data.act[:] = act
                mujoco.mj_forward(m, self.raw.data)
        return self._start(None if self.layout == "qpos,qvel" else self._mujoco_state()[: m.nq + m.nv])

    # ---- stepping ----
    def step(self, u: npt.ArrayLike) -> np.ndarray:
        """Applies the action ``u`` (clipped to the Box) for one dt; returns the next state.
        Termination and truncation are recorded (``status``), not acted on."""
        if not self.ready:
            raise InvalidInput(f"{self.env_id}: not reset yet (or reset needed after a failure)")
        u = as_input(u, self.nu, "u")
        clipped = np.clip(u, self.u_lo, self.u_hi)
        self.last_clipped = bool(np.any(clipped != u))
        self.clipped_inputs += int(np.count_nonzero(clipped != u))
        a = self.action_space
        if np.issubdtype(a.dtype, np.integer):
            action = np.rint(clipped).astype(a.dtype).reshape(a.shape)
        else:
            action = clipped.reshape(a.shape)
        obs, reward, terminated, truncated, _ = self.env.step(action)
        self.k += 1
        self.steps += 1
        self.reward = float(reward)
        if terminated and not self.terminated:
            self.terminations += 1
            self._ended("terminated")
        if truncated and not self.truncated:
            self.truncations += 1
            self._ended("truncated")
        self.terminated, self.truncated = bool(terminated), bool(truncated)
        return self._state(obs)

    def _ended(self, how: str) -> None:
        if self.on_episode_end is not None:
            self.on_episode_end(f"{self.env_id}: episode {how} at step {self.k} (reward {self.reward:.4g}); stepping goes on until the next reset")

    def counters(self) -> dict[str, int]:
        """``steps``, ``episodes`` (resets), ``terminations``, ``truncations``, ``clipped_inputs``."""
        return dict(steps=self.steps, episodes=self.episodes, terminations=self.terminations, truncations=self.truncations, clipped_inputs=self.clipped_inputs)

    def status(self) -> dict[str, Any]:
        """The last step's status (``terminated``, ``truncated``, ``reward``, ``k``) and the
        counters (the command line prints every episode end)."""
        return dict(terminated=self.terminated, truncated=self.truncated, reward=self.reward, k=self.k, **self.counters())

    def step_status(self) -> dict[str, bool]:
        """The last ``step``'s flags for the step reply (PROTOCOL.md §4): Gymnasium's
        ``terminated`` and ``truncated`` as the environment returned them, and ``clipped`` when
        the action was clipped to the Box. Stepping goes on either way."""
        return dict(terminated=self.terminated, truncated=self.truncated, clipped=self.last_clipped)

    def close(self) -> None:
        """Closes the environment; prints the counters to standard error when an episode ended or an action was clipped."""
        if self.terminations or self.truncations or self.clipped_inputs:
            print(f"{self.env_id}: {self.counters()}", file=sys.stderr, flush=True)
        self.ready = False
        self.env.close()
