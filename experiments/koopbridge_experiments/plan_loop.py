"""A plan corrected by a position loop, for arms commanded in joint velocities: the planned
velocities (the inputs and the planned state's q̇ alike) minus ``gain · (q − q_plan)``; the
error-state MPC then plans around the corrected plan (docs/log/2026-12.md, session 8). Through the
bridge the orchestrator does it (``[control] position_loop``); this is the second computation the
robot scenarios' smoke tests check the engine's rows against."""

from __future__ import annotations

import numpy as np

__all__ = ["corrected_plan"]


def corrected_plan(x: np.ndarray, state: np.ndarray, inputs: np.ndarray, q: slice | list[int], qd: slice | list[int], gain: float,
                   limit: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """The planned state at this step and the feed-forward window ``inputs`` (H, nu) corrected
    by ``-gain · (x[q] − state[q])`` on the velocities ``state[qd]`` and on every input, the
    inputs clipped to ``±limit``. ``q``, ``qd``: where the joint positions and velocities sit in
    the state (the inputs command the velocities, in the same order)."""
    corr = -gain * (x[q] - state[q])
    s = np.array(state, dtype=float, copy=True)
    s[qd] += corr
    return s, np.clip(inputs + corr, -limit, limit)
