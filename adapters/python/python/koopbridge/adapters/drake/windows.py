"""Blocks of Gen3 windows cut from planned trajectories, deterministic by ``(seed, window)`` and
so resumable by block: the ``collect`` of the Drake simulator for the SDK's (and the Zenoh
``collect`` request's) ``{"kind": "planned"}`` policy.

Window ``i`` belongs to plan ``p = i // windows_per_plan``: a start and a goal drawn
collision-free (``random_goals``, 2 cm margin) from ``(seed, p)`` and planned by the two-pass
``Gen3Planner`` (a draw the planner refuses is redrawn, the attempt counted in the seed). Its
``windows_per_plan`` windows start at evenly spaced planned states along the plan; each resets
the simulation to that planned state ``[q, q̇]`` and executes the next ``T`` planned velocities
as commands (plus, with a ``dither``, ``U(±dither)`` per joint and step drawn from
``(seed, window)``: excitation off the plan). Since ``[q, q̇]`` is the simulator's whole state, that is what executing the plan
from its start would give had the arm been on the plan there; the windows stay within SPEC's
"constrained, expert-guided" data (every command a planned velocity, every start a planned
state) without one plan per window or executing whole plans to reach a window.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..._native import InvalidInput, Unsupported
from ...collect import PlannedPolicy, Windows
from .model import VELOCITY_LIMITS

__all__ = ["DESCRIPTION", "PlannedPolicy", "collect_planned", "plan_for"]

#: Redraws of a plan's start and goal before giving up on it.
MAX_ATTEMPTS = 20

#: How planned windows are made, for dataset metadata (the simulator's ``info().extra``; the
#: orchestrator appends it to the dataset's ``policy``).
DESCRIPTION = (
    "plan p = window // windows_per_plan (default 20); its start and goal drawn uniformly within the joint limits, "
    "collision-free with a 2 cm margin, from SeedSequence([seed, 7, p, attempt]) (attempt = redraws of infeasible pairs); "
    "two-pass KinematicTrajectoryOptimization (10 control points, duration in [0.5, 5] s, then self/table collision), "
    "SNOPT with IPOPT as fallback; windows start at evenly spaced planned states and apply the planned velocities "
    "(+ U(+-dither) per joint and step from SeedSequence([seed, 11, window]) when the policy has a dither)"
)


def plan_for(planner: Any, seed: int, p: int) -> tuple[Any, int]:
    """Plan ``p`` of a collection with ``seed`` and the attempt that gave it."""
    from .plan import Infeasible, random_goals

    for attempt in range(MAX_ATTEMPTS):
        s = int(np.random.SeedSequence([seed, 7, p, attempt]).generate_state(1, np.uint64)[0])
        start, goal = random_goals(s, 2, planner=planner, margin=0.02)
        try:
            return planner.plan(start, goal), attempt
        except Infeasible:
            continue
    raise Unsupported(f"plan {p} of seed {seed}: no feasible start/goal pair in {MAX_ATTEMPTS} draws")


def collect_planned(sim: Any, planner: Any, policy: PlannedPolicy, seed: int, n_windows: int, T: int, start: int = 0) -> Windows:
    """Windows ``start .. start + n_windows − 1`` (see the module doc) on the Drake simulator
    ``sim``; ``reset_seeds[i]`` holds window i's plan index ``p`` (the windows reset to planned
    states, not by seed)."""
    if n_windows < 0 or T < 1 or seed < 0 or start < 0:
        raise InvalidInput(f"collect: n_windows, seed, start must be >= 0 and T >= 1, got {n_windows}, {seed}, {start}, {T}")
    K = policy.windows_per_plan
    xs = np.empty((n_windows, T + 1, 14))
    us = np.empty((n_windows, T, 7))
    plans = np.empty(n_windows, dtype=np.uint64)
    cached: tuple[int, np.ndarray, np.ndarray] | None = None
    for n, i in enumerate(range(start, start + n_windows)):
        p, j = divmod(i, K)
        if cached is None or cached[0] != p:
            plan, _ = plan_for(planner, seed, p)
            _, q, qd = plan.sample(sim.dt)
            # Enough samples for a window at every offset: pad with the goal at rest.
            pad = max(0, T + 1 - len(q))
            q = np.concatenate([q, np.tile(q[-1], (pad, 1))])
            qd = np.concatenate([qd, np.zeros((pad, 7))])
            cached = (p, q, qd)
        _, q, qd = cached
        last = len(q) - 1 - T
        s = 0 if K == 1 else int(round(j * last / (K - 1)))
        u = qd[s : s + T]
        if policy.dither > 0:
            u = u + np.random.default_rng(np.random.SeedSequence([seed, 11, i])).uniform(-policy.dither, policy.dither, u.shape)
        u = np.clip(u, -VELOCITY_LIMITS, VELOCITY_LIMITS)
        xs[n, 0] = sim.reset(x0=np.r_[np.clip(q[s], sim.q_lower, sim.q_upper), np.clip(qd[s], -VELOCITY_LIMITS, VELOCITY_LIMITS)])
        for t in range(T):
            xs[n, t + 1] = sim.step(u[t])
        us[n] = u
        plans[n] = p
    return Windows(x=xs, u=us, seed=seed, start=start, reset_seeds=plans)
