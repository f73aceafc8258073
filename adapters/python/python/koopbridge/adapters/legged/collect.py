"""Expert data of a legged robot, run in the simulator's own process (the ``collect`` policies
``expert`` and ``expert+noise``): the robot's walking policy under random velocity commands,
windows cut from episodes, deterministic by ``(policy, seed, window)``. Robot-agnostic: the
simulator implements ``ExpertRobot``.

An episode ``e`` holds windows ``e·K .. e·K + K − 1`` (K = ``windows_per_episode``). It starts
with a seeded reset drawn from ``numpy.random.default_rng([seed, e, 1])``, walks ``warmup``
seconds unrecorded, then records its K windows back to back (window j's last state is window
j+1's first). The same generator draws, in this order as the episode goes: the reset seed, a
velocity command ``U(command_low, command_high)`` at the start and every ``command_every``
seconds (the robot's command follows it through its slew limit), the noise ``N(0, noise²)`` on
each step's joint targets (``expert+noise``), and a push (``U(±push)`` m/s added to the base's
horizontal world velocity) every ``push_every`` seconds, at a window boundary only, so that
every recorded transition is the robot's own dynamics. Targets are clipped to the input bounds
(``u_lo``, ``u_hi``) and the recorded inputs are the targets applied. A fall inside a window discards it and the
episode restarts (a new reset from the same generator, warm-up again) at that window; a window
depends only on ``(policy, seed, window)`` still, so blocks resume bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ..._native import InvalidInput, KoopbridgeError
from ...collect import Windows

__all__ = ["ExpertPolicy", "ExpertRobot", "collect_expert", "expert_rollouts"]

#: Restarts after falls allowed in one episode before the collection gives up.
MAX_RESTARTS = 50
#: The settings of an expert policy's JSON form (besides ``kind``).
SETTINGS = ("noise", "command_low", "command_high", "command_every", "push", "push_every", "warmup", "windows_per_episode")


class ExpertRobot(Protocol):
    """What ``collect_expert`` needs from a legged simulator."""

    dt: float
    nx: int
    nu: int
    u_lo: np.ndarray
    u_hi: np.ndarray
    command_slew: np.ndarray

    def reset(self, seed: int | None = None, x0: Any = None, perturbation: dict[str, Any] | None = None) -> np.ndarray: ...
    def step(self, u: Any) -> np.ndarray: ...
    def state(self) -> np.ndarray: ...
    def expert_reset(self) -> None: ...
    def expert_targets(self, command: np.ndarray) -> np.ndarray: ...
    def advance(self, targets: np.ndarray) -> np.ndarray: ...
    def is_fallen(self) -> bool: ...
    def push(self, dv_xy: np.ndarray) -> None: ...
    def remember(self, x: np.ndarray) -> None: ...


def _vec3(v: Any, what: str) -> tuple[float, float, float]:
    if not isinstance(v, (list, tuple)) or len(v) != 3 or not all(isinstance(a, (int, float)) and not isinstance(a, bool) and math.isfinite(a) for a in v):
        raise InvalidInput(f"expert policy: {what} must be 3 finite numbers (vx, vy, wz), got {v!r}")
    return (float(v[0]), float(v[1]), float(v[2]))


def _number(v: Any, what: str, *, positive: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0 or (positive and v == 0):
        raise InvalidInput(f"expert policy: {what} must be a finite number {'> 0' if positive else '>= 0'}, got {v!r}")
    return float(v)


@dataclass(frozen=True)
class ExpertPolicy:
    """The settings of an ``expert`` / ``expert+noise`` collection (see the module docstring).

    ``noise``: σ of the Gaussian on the joint targets, rad (``expert``: 0; ``expert+noise``:
    > 0, default 0.05); ``command_low``/``command_high``: the box of (vx m/s, vy m/s, ωz rad/s)
    commands; ``command_every``, ``warmup``, ``push_every``: seconds; ``push``: the largest push,
    m/s (0: none); ``windows_per_episode`` ≥ 1.
    """

    kind: str = "expert"
    noise: float = 0.0
    command_low: tuple[float, float, float] = (-0.5, -0.3, -0.8)
    command_high: tuple[float, float, float] = (1.0, 0.3, 0.8)
    command_every: float = 2.0
    push: float = 0.0
    push_every: float = 4.0
    warmup: float = 1.0
    windows_per_episode: int = 50

    @staticmethod
    def from_json(d: Mapping[str, Any]) -> ExpertPolicy:
        """The settings of ``{"kind": "expert" | "expert+noise", ...}``; ``InvalidInput`` for
        an unknown field or a bad value."""
        kind = d.get("kind")
        if kind not in ("expert", "expert+noise"):
            raise InvalidInput(f"expert policy: kind must be 'expert' or 'expert+noise', got {kind!r}")
        keys = set(SETTINGS)
        unknown = set(d) - keys - {"kind"}
        if unknown:
            raise InvalidInput(f"expert policy: unknown fields {sorted(unknown)} (known: {sorted(keys)})")
        if kind == "expert" and d.get("noise", 0) not in (0, 0.0):
            raise InvalidInput("expert policy: 'expert' has no noise; ask for 'expert+noise'")
        noise = _number(d.get("noise", 0.05 if kind == "expert+noise" else 0.0), "noise", positive=kind == "expert+noise")
        low = _vec3(d.get("command_low", [-0.5, -0.3, -0.8]), "command_low")
        high = _vec3(d.get("command_high", [1.0, 0.3, 0.8]), "command_high")
        if any(lo > hi for lo, hi in zip(low, high, strict=True)):
            raise InvalidInput(f"expert policy: command_low {list(low)} is above command_high {list(high)}")
        k = d.get("windows_per_episode", 50)
        if isinstance(k, bool) or not isinstance(k, int) or k < 1:
            raise InvalidInput(f"expert policy: windows_per_episode must be an integer >= 1, got {k!r}")
        return ExpertPolicy(
            kind=str(kind),
            noise=noise,
            command_low=low,
            command_high=high,
            command_every=_number(d.get("command_every", 2.0), "command_every", positive=True),
            push=_number(d.get("push", 0.0), "push"),
            push_every=_number(d.get("push_every", 4.0), "push_every", positive=True),
            warmup=_number(d.get("warmup", 1.0), "warmup"),
            windows_per_episode=k,
        )

    def to_json(self) -> dict[str, Any]:
        """All settings as JSON."""
        return {"kind": self.kind, **{k: (list(v) if isinstance(v, tuple) else v) for k in SETTINGS for v in [getattr(self, k)]}}


@dataclass
class _Episode:
    """One episode's generator and walking state."""

    robot: ExpertRobot
    policy: ExpertPolicy
    rng: np.random.Generator
    T: int
    reset_seed: int = 0
    k: int = 0  # steps since the (re)start
    command: np.ndarray = field(default_factory=lambda: np.zeros(3))
    goal: np.ndarray = field(default_factory=lambda: np.zeros(3))
    restarts: int = 0

    def __post_init__(self) -> None:
        dt = self.robot.dt
        self.command_steps = max(1, round(self.policy.command_every / dt))
        self.warmup_steps = round(self.policy.warmup / dt)
        # Pushes at window boundaries: every push_every seconds rounded up to whole windows.
        self.push_windows = max(1, math.ceil(round(self.policy.push_every / dt) / self.T))
        self.low, self.high = np.array(self.policy.command_low), np.array(self.policy.command_high)

    def start(self) -> np.ndarray:
        """(Re)starts: a seeded reset, then the unrecorded warm-up; returns the state."""
        self.reset_seed = int(self.rng.integers(0, 2**63))
        self.robot.reset(seed=self.reset_seed)
        self.robot.expert_reset()
        self.k = 0
        self.command = np.zeros(3)
        for _ in range(self.warmup_steps):
            self.step()
        return np.asarray(self.robot.state(), dtype=np.float64)

    def step(self, apply: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One expert step through ``apply`` (default: the robot's ``advance``); returns (next
        state, the targets applied)."""
        r = self.robot
        if self.k % self.command_steps == 0:
            self.goal = self.rng.uniform(self.low, self.high)
        self.command = self.command + np.clip(self.goal - self.command, -r.command_slew, r.command_slew)
        targets = r.expert_targets(self.command)
        if self.policy.noise > 0:
            targets = targets + self.rng.normal(0.0, self.policy.noise, targets.shape)
        targets = np.clip(targets, r.u_lo, r.u_hi)
        self.k += 1
        return (apply or r.advance)(targets), targets


def collect_expert(robot: ExpertRobot, policy: ExpertPolicy, seed: int, n_windows: int, T: int, start: int = 0) -> Windows:
    """Windows ``start .. start + n_windows − 1`` of the expert collection with ``seed`` (see the
    module docstring); ``x`` ``(n, T+1, nx)``, ``u`` ``(n, T, nu)``. Raises ``InvalidInput`` for
    bad sizes, ``KoopbridgeError`` when an episode falls more than ``MAX_RESTARTS`` times, and
    lets the simulator's own failures through."""
    if n_windows < 0 or T < 1 or seed < 0 or start < 0:
        raise InvalidInput(f"collect: n_windows, seed and start must be >= 0 and T >= 1, got {n_windows}, {seed}, {start}, {T}")
    K = policy.windows_per_episode
    xs = np.empty((n_windows, T + 1, robot.nx))
    us = np.empty((n_windows, T, robot.nu))
    seeds = np.empty(n_windows, dtype=np.uint64)
    i = start
    while i < start + n_windows:
        e, j0 = divmod(i, K)
        last = min((e + 1) * K, start + n_windows) - e * K  # windows of this episode to reach
        ep = _Episode(robot, policy, np.random.default_rng([seed, e, 1]), T)
        x = ep.start()
        j = 0
        while j < last:
            w_x = np.empty((T + 1, robot.nx))
            w_u = np.empty((T, robot.nu))
            w_x[0] = x
            if j >= j0:
                robot.remember(x)  # a later reset(x0=x) restores the hidden state too
            fell = False
            for t in range(T):
                w_x[t + 1], w_u[t] = ep.step()
                if robot.is_fallen():
                    fell = True
                    break
            if fell:
                ep.restarts += 1
                if ep.restarts > MAX_RESTARTS:
                    raise KoopbridgeError(f"expert collection: episode {e} of seed {seed} fell {ep.restarts} times; is the expert able to walk here?")
                x = ep.start()
                continue
            if j >= j0:
                row = e * K + j - start
                xs[row], us[row], seeds[row] = w_x, w_u, ep.reset_seed
            x = w_x[T]
            j += 1
            if policy.push > 0 and j < last and j % ep.push_windows == 0:
                robot.push(ep.rng.uniform(-policy.push, policy.push, 2))
                x = np.asarray(robot.state(), dtype=np.float64)
        i = e * K + last
    return Windows(x=xs, u=us, seed=seed, start=start, reset_seeds=seeds)



def _expert_run(robot: ExpertRobot, policy: ExpertPolicy, rng: np.random.Generator, T: int,
                perturbation: Mapping[str, Any] | None) -> tuple[np.ndarray, np.ndarray]:
    """One episode from ``rng``: the seeded reset and warm-up; with ``perturbation`` (not
    ``None``) the robot then reset to that state as a reset request would (``reset(x0,
    perturbation)``: the same state, the actuators' memory cold) and ``T`` expert steps through
    ``step`` (the push at its step), else ``T`` steps on from the warm-up as the collection
    runs them (ending at a fall, where the collection restarts the episode). A perturbed run
    goes on after a fall. Returns x (T+1, nx) and each state's fall flag."""
    ep = _Episode(robot, policy, rng, T)
    x = np.empty((T + 1, robot.nx))
    fell = np.zeros(T + 1, dtype=bool)
    x[0] = ep.start()
    apply = None
    if perturbation is not None:
        x[0] = robot.reset(x0=x[0], perturbation=dict(perturbation))
        apply = robot.step
    for t in range(T):
        x[t + 1], _ = ep.step(apply)
        fell[t + 1] = robot.is_fallen()
        if fell[t + 1] and perturbation is None:  # the collection restarts here
            return x[: t + 2], fell[: t + 2]
    return x, fell


def expert_rollouts(robot: ExpertRobot, policy: ExpertPolicy, seed: int, window: int, T: int,
                    perturbations: list[Mapping[str, Any]]) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """The expert's own closed loop on the tracking task of a reference: window ``window`` of
    the collection with ``seed`` and one window per episode (``legged_references``' references)
    walked again — the same episode, warm-up and velocity commands — once as collected (the
    reference itself, bit for bit: the caller's check that this is its task) and once per entry
    of ``perturbations`` from the reference's first state as the scenario engine's reset request
    starts every row (a reset request's ``perturbation``: ``mass_scale``, ``friction_scale``,
    ``push = {step, velocity}``; ``{}`` for the nominal robot), the expert acting instead of the
    MPC, not stopped by a fall. Returns the collected run's states and, per perturbation, the
    states and fall flags. ``InvalidInput`` for a policy with noise or several windows per
    episode; ``KoopbridgeError`` when the episode keeps falling."""
    if policy.windows_per_episode != 1 or policy.noise > 0:
        raise InvalidInput("expert rollouts: the references' policy has one window per episode and no noise")
    rng = np.random.default_rng([seed, window, 1])
    for _ in range(MAX_RESTARTS + 1):  # the collection restarts an episode that falls
        at_start = rng.bit_generator.state
        collected, fell = _expert_run(robot, policy, rng, T, None)
        if not fell.any():
            break
    else:
        raise KoopbridgeError(f"expert rollouts: episode {window} of seed {seed} fell {MAX_RESTARTS + 1} times")
    runs = []
    for p in perturbations:
        rng.bit_generator.state = at_start
        runs.append(_expert_run(robot, policy, rng, T, p))
    return collected, runs
