"""The legged tracking task's parts (SPEC "Legged robots", issues 25 §3 and 30; the Go2's state
layout by default, another robot's through ``StateLayout``): held-out expert references,
the survival metric, one closed loop through the bridge (adapter in lockstep, MPC service
deciding every step), the open-loop replay floor, and the closed loops cut into training
windows (on-policy aggregation).

Survival of a run ``x_0 .. x_n`` against a reference ``r_0 .. r_L``: with
``e_k = mean_j |q_k,j − q^ref_k,j|`` (the state's joint positions, rad: the Go2's 12, the G1's 21) and ``fail_k`` = ``e_k >
threshold`` or the base fallen at step k (``FallRule``), survival = ``min{k ≥ 1 : fail_k} − 1``
— the steps completed before the first failing one — or ``L`` when no step of the reference
fails (a run cut short by a failure has ``n = `` that step).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "GO2_LAYOUT",
    "REFERENCE_SEED",
    "StateLayout",
    "Reference",
    "Rollout",
    "fallen_mask",
    "joint_errors",
    "make_references",
    "reference_window",
    "replay",
    "rollout_windows",
    "survival",
    "track",
]

#: Seed of the reference rollouts. The expert data (``go2_data``) use seed 42, so its episodes
#: draw from ``default_rng([42, e, 1])``; reference i draws its reset and every velocity command
#: from ``default_rng([REFERENCE_SEED, i, 1])``, a stream no training episode uses: the
#: commands are continuous draws the data never saw.
REFERENCE_SEED = 90_042
#: Go2 layout of the 35-D state: joint positions and the quaternion / base height.
Q_SLICE = slice(10, 22)
QUAT_SLICE = slice(0, 4)
HEIGHT_INDEX = 34


@dataclass(frozen=True)
class StateLayout:
    """Where a legged robot's state keeps what survival scores: the joint positions ``q`` (a
    slice), the base quaternion ``quat`` (a slice) and the base height (an index)."""

    q: slice
    quat: slice
    height: int


#: The Go2's 35-D state (the default of every function here).
GO2_LAYOUT = StateLayout(Q_SLICE, QUAT_SLICE, HEIGHT_INDEX)


@dataclass(frozen=True)
class Reference:
    """One held-out expert rollout: states ``x`` ``(L+1, nx)``, the expert's applied joint
    targets ``u`` ``(L, nu)`` (``u[k]`` drives ``x[k]`` to ``x[k+1]``), its index and seed."""

    x: np.ndarray
    u: np.ndarray
    index: int
    seed: int

    @property
    def steps(self) -> int:
        """The reference length L (transitions)."""
        return len(self.u)


@dataclass
class Rollout:
    """One closed loop (or replay): states ``x`` ``(n+1, nx)``, inputs ``u`` ``(n, nu)``,
    survival, the MPC's solve times in the service and round trips (s) and statuses."""

    x: np.ndarray
    u: np.ndarray
    survival: int
    solve_s: list[float] = field(default_factory=list)
    round_trip_s: list[float] = field(default_factory=list)
    statuses: dict[str, int] = field(default_factory=dict)
    fell: bool = False
    errors: list[str] = field(default_factory=list)


def joint_errors(x: np.ndarray, ref: np.ndarray, q: slice = Q_SLICE) -> np.ndarray:
    """``e_k``: the mean absolute joint-position error of each row of ``x`` against the same
    row of ``ref`` (rad)."""
    n = len(x)
    return np.mean(np.abs(np.asarray(x)[:, q] - np.asarray(ref)[:n, q]), axis=1)


def fallen_mask(x: np.ndarray, fallen: Callable[[np.ndarray, float], bool], layout: StateLayout = GO2_LAYOUT) -> np.ndarray:
    """Whether each state's base has fallen (``fallen(quat, height)``, the robot's ``FallRule``;
    ``layout``: where the state keeps them, the Go2's by default)."""
    return np.array([bool(fallen(xi[layout.quat], float(xi[layout.height]))) for xi in np.asarray(x)], dtype=bool)


def survival(errors: np.ndarray, fell: np.ndarray, length: int, threshold: float = 0.16) -> int:
    """Survival steps (module docstring) from the per-state errors ``e_0 .. e_n`` and fall flags
    of a run against a reference of ``length`` transitions; step 0 (the shared start) never
    counts as a failure."""
    errors, fell = np.asarray(errors, float), np.asarray(fell, bool)
    if errors.shape != fell.shape:
        raise ValueError(f"errors {errors.shape} and falls {fell.shape} differ in shape")
    n = min(len(errors) - 1, length)
    fail = (errors[1 : n + 1] > threshold) | fell[1 : n + 1] | ~np.isfinite(errors[1 : n + 1])
    hits = np.flatnonzero(fail)
    if hits.size:
        return int(hits[0])
    if n < length:
        raise ValueError(f"a run of {n} steps without a failure cannot be scored against {length} steps")
    return length


def make_references(n: int, steps: int, seed: int = REFERENCE_SEED, *, warmup: float = 1.0, command_every: float = 2.0,
                    sim: Any = None, skipped: list[dict[str, Any]] | None = None, probe: Any = None, policy: Any = None) -> list[Reference]:
    """``n`` held-out expert references of ``steps`` transitions, in-process on a fresh
    ``Go2Simulator`` (the adapter's defaults): rollout i is the expert collection's window i
    with one window per episode (``windows_per_episode`` 1, T = ``steps``), under ``seed``: a
    seeded reset, ``warmup`` s of walking unrecorded, then ``steps`` recorded steps under a
    random velocity command changed every ``command_every`` s. The references are the first
    ``n`` rollouts whose first state a fresh simulator accepts as ``reset(x0)`` (it refuses a
    base or leg too deep in the floor; until the adapter's 06:13 change of 4 Dec 2026 that
    refused 2 of the first 50 expert starts); the refused ones are appended to ``skipped``.
    Another robot: ``sim`` (collecting), ``probe`` (a memoryless simulator judging the starts)
    and ``policy`` (its expert's settings with one window per episode) given."""
    from .._native import InvalidInput
    from ..adapters.go2_sim import Go2Simulator
    from ..adapters.legged_collect import ExpertPolicy

    if n < 1 or steps < 1:
        raise ValueError(f"references: need n >= 1 and steps >= 1, got {n}, {steps}")
    sim = sim or Go2Simulator(on_fall=None)
    probe = probe or Go2Simulator(on_fall=None, memory=0)
    policy = policy or ExpertPolicy(windows_per_episode=1, warmup=warmup, command_every=command_every)
    out: list[Reference] = []
    start = 0
    while len(out) < n:
        if start > 2 * n + 20:
            raise ValueError(f"references: {start - len(out)} of {start} expert rollouts start in states the simulator refuses")
        w = sim.collect(policy, seed, n - len(out), steps, start=start)
        for j in range(len(w.x)):
            try:
                probe.reset(x0=w.x[j, 0])
            except InvalidInput as e:
                if skipped is not None:
                    skipped.append(dict(index=start + j, reason=str(e)))
                continue
            out.append(Reference(x=w.x[j].copy(), u=w.u[j].copy(), index=start + j, seed=seed))
        start += len(w.x)
    return out


def reference_window(ref: np.ndarray, k: int, horizon: int) -> np.ndarray:
    """Rows ``k+1 .. k+horizon`` of ``ref`` (the states the plan from step k aims at; the last
    row held past the end), ``(horizon, nx)``."""
    idx = np.minimum(np.arange(k + 1, k + 1 + horizon), len(ref) - 1)
    return ref[idx]


def _failed(x: np.ndarray, ref_row: np.ndarray, fallen: Callable[[np.ndarray, float], bool], threshold: float,
            layout: StateLayout = GO2_LAYOUT) -> tuple[bool, bool]:
    e = float(np.mean(np.abs(x[layout.q] - ref_row[layout.q])))
    f = bool(fallen(x[layout.quat], float(x[layout.height])))
    return (not np.isfinite(e)) or e > threshold or f, f


def track(client: Any, sim_id: str, mpc_id: str, model: str, ref: Reference, fallen: Callable[[np.ndarray, float], bool], *,
          horizon: int = 15, threshold: float = 0.16, stop_at_failure: bool = True, solve_timeout: float = 60.0,
          error_state: bool = False, layout: StateLayout = GO2_LAYOUT) -> Rollout:
    """Resets simulator ``sim_id`` to the reference's first state and lets MPC service ``mpc_id``
    (model ``model``, configured already) choose every input from the state and the next
    ``horizon`` reference states (SPEC's formulation); stops at the first failing step
    (``stop_at_failure``), a fall or the reference's end. A step the simulator refuses
    (``sim_failure``) ends the run as a fall, and is noted. ``error_state``: instead the
    error-state MPC about the reference as a plan (its state at step k, the expert's targets
    k .. k+H−1 as feed-forward; lifted-linear models only), not SPEC's formulation. ``layout``:
    the robot's state layout (the Go2's by default)."""
    from .. import KoopbridgeError

    nu = ref.u.shape[1]
    x = np.asarray(client.reset(sim_id, x0=ref.x[0]), float)
    xs, us = [x], []
    out = Rollout(x=np.empty(0), u=np.empty(0), survival=0)
    for k in range(ref.steps):
        t = time.perf_counter()
        if error_state:
            ff = ref.u[np.minimum(np.arange(k, k + horizon), ref.steps - 1)]
            sol = client.solve(mpc_id, x, ref.x[k], model=model, nu=nu, timeout=solve_timeout, feedforward=ff)
        else:
            sol = client.solve(mpc_id, x, reference_window(ref.x, k, horizon), model=model, nu=nu, timeout=solve_timeout)
        out.round_trip_s.append(time.perf_counter() - t)
        out.solve_s.append(float(sol["solve_time"]))
        out.statuses[str(sol["status"])] = out.statuses.get(str(sol["status"]), 0) + 1
        u = np.asarray(sol["u"], float)[0]
        try:
            x = np.asarray(client.step(sim_id, u)[2], float)
        except KoopbridgeError as e:
            out.errors.append(f"step {k + 1}: {e}")
            xs.append(np.full_like(x, np.nan))
            us.append(u)
            break
        xs.append(x)
        us.append(u)
        failed, fell = _failed(x, ref.x[k + 1], fallen, threshold, layout)
        if fell or (failed and stop_at_failure):
            break
    out.x, out.u = np.array(xs), np.array(us)
    x_scored = out.x.copy()
    x_scored[~np.all(np.isfinite(x_scored), axis=1)] = np.nan
    fell_mask = np.array([not np.all(np.isfinite(r)) or bool(fallen(r[layout.quat], float(r[layout.height]))) for r in x_scored])
    out.survival = survival(joint_errors(x_scored, ref.x, layout.q), fell_mask, ref.steps, threshold)
    out.fell = bool(fell_mask.any())
    return out


def replay(client: Any, sim_id: str, ref: Reference, fallen: Callable[[np.ndarray, float], bool], *, threshold: float = 0.16,
           layout: StateLayout = GO2_LAYOUT) -> Rollout:
    """The open-loop floor: the expert's recorded targets replayed from the reference's first
    state through the same adapter (every step, so that the whole run can be plotted) until its
    end or a fall; ``layout``: the robot's state layout (the Go2's by default)."""
    from .. import KoopbridgeError

    x = np.asarray(client.reset(sim_id, x0=ref.x[0]), float)
    xs = [x]
    errors: list[str] = []
    for k in range(ref.steps):
        try:
            x = np.asarray(client.step(sim_id, ref.u[k])[2], float)
        except KoopbridgeError as e:
            errors.append(f"step {k + 1}: {e}")
            xs.append(np.full_like(x, np.nan))
            break
        xs.append(x)
        if fallen(x[layout.quat], float(x[layout.height])):
            break
    X = np.array(xs)
    fell_mask = np.array([not np.all(np.isfinite(r)) or bool(fallen(r[layout.quat], float(r[layout.height]))) for r in X])
    s = survival(joint_errors(X, ref.x, layout.q), fell_mask, ref.steps, threshold)
    return Rollout(x=X, u=ref.u[: len(X) - 1].copy(), survival=s, fell=bool(fell_mask.any()), errors=errors)


def rollout_windows(rollouts: list[Rollout], T: int, fallen: Callable[[np.ndarray, float], bool],
                    layout: StateLayout = GO2_LAYOUT) -> tuple[np.ndarray, np.ndarray]:
    """The closed loops cut into back-to-back windows of ``T`` transitions (the dataset layout:
    ``x`` ``(n, T+1, nx)``, ``u`` ``(n, T, nu)``), each run only up to its last finite, upright
    state (a window never holds a fallen state, as the expert data's never do)."""
    xs, us = [], []
    for r in rollouts:
        ok = np.all(np.isfinite(r.x), axis=1) & ~fallen_mask(np.nan_to_num(r.x), fallen, layout)
        bad = np.flatnonzero(~ok)
        n = int(bad[0]) - 1 if bad.size else len(r.x) - 1  # transitions whose both ends are good
        for s in range(0, n - T + 1, T):
            xs.append(r.x[s : s + T + 1])
            us.append(r.u[s : s + T])
    if not xs:
        nx = rollouts[0].x.shape[1] if rollouts else 0
        nu = rollouts[0].u.shape[1] if rollouts and rollouts[0].u.ndim == 2 else 0
        return np.empty((0, T + 1, nx)), np.empty((0, T, nu))
    return np.array(xs), np.array(us)
