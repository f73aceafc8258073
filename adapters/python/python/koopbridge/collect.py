"""In-process data collection: blocks of windows run by a simulator itself, deterministic by
seed and resumable by block. A policy is plain JSON (``{"kind": "uniform", ...}`` or
``{"kind": "planned", ...}``) so that the same request can travel over Zenoh; window ``i``
depends only on ``(seed, i)``."""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ._native import InvalidInput, Unsupported
from .simulator import SimInfo, Simulator

__all__ = [
    "SIMULATOR_POLICY_KINDS",
    "Collector",
    "PlannedPolicy",
    "Policy",
    "SimulatorPolicy",
    "UniformPolicy",
    "Windows",
    "collect_windows",
    "policy_from_json",
    "window_rng",
]

#: Policy kinds that only a simulator with its own ``collect`` runs (``SimulatorPolicy``): a
#: legged robot's expert walking policy, alone or with Gaussian noise on its joint targets
#: (``koopbridge.adapters.legged.collect``).
SIMULATOR_POLICY_KINDS = ("expert", "expert+noise")


class Policy(Protocol):
    """Draws the inputs of one window."""

    def inputs(self, rng: np.random.Generator, T: int, info: SimInfo) -> np.ndarray:
        """``(T, nu)`` inputs for one window, drawn from ``rng`` only."""
        ...

    def to_json(self) -> dict[str, Any]:
        """The policy as JSON (what a collect request would carry)."""
        ...


@dataclass(frozen=True)
class UniformPolicy:
    """A fresh ``u ~ U(low, high)`` every step (SPEC's data); ``low``/``high`` default to the
    simulator's bounds (``info().u_min``/``u_max``), which must then be finite; one value
    applies to every input. ``x0_low``/``x0_high`` (``nx`` values each, together): every
    window resets to ``x0 ~ U(x0_low, x0_high)`` drawn from its generator after the reset seed
    (``reset(x0=...)``), instead of the seeded reset."""

    low: tuple[float, ...] | None = None
    high: tuple[float, ...] | None = None
    x0_low: tuple[float, ...] | None = None
    x0_high: tuple[float, ...] | None = None

    def x0_box(self, info: SimInfo) -> tuple[np.ndarray, np.ndarray] | None:
        """The initial-state box checked against ``info`` (``None`` without one)."""
        if self.x0_low is None and self.x0_high is None:
            return None
        if self.x0_low is None or self.x0_high is None:
            raise InvalidInput("uniform policy: x0_low and x0_high go together (the initial-state box's two corners)")
        lo, hi = np.array(self.x0_low, dtype=float), np.array(self.x0_high, dtype=float)
        if lo.shape != (info.nx,) or hi.shape != (info.nx,):
            raise InvalidInput(f"uniform policy: x0_low and x0_high must have {info.nx} values (one per state), got {lo.size} and {hi.size}")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)):
            raise InvalidInput(f"uniform policy: the initial-state box must be finite with x0_low <= x0_high, got {lo.tolist()}, {hi.tolist()}")
        return lo, hi

    def bounds(self, info: SimInfo) -> tuple[np.ndarray, np.ndarray]:
        """The box inputs are drawn from, checked against ``info``."""
        lo = np.array(self.low if self.low is not None else info.u_min, dtype=float)
        hi = np.array(self.high if self.high is not None else info.u_max, dtype=float)
        lo, hi = (np.full(info.nu, b.item()) if b.size == 1 else b for b in (lo, hi))
        if lo.shape != (info.nu,) or hi.shape != (info.nu,):
            raise InvalidInput(f"uniform policy: bounds of {lo.size} and {hi.size} values for {info.nu} inputs")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)):
            raise InvalidInput(f"uniform policy: bounds must be finite with low <= high, got {lo.tolist()}, {hi.tolist()}")
        return lo, hi

    def inputs(self, rng: np.random.Generator, T: int, info: SimInfo) -> np.ndarray:
        lo, hi = self.bounds(info)
        return rng.uniform(lo, hi, size=(T, info.nu))

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"kind": "uniform"}
        if self.low is not None:
            d["low"] = list(self.low)
        if self.high is not None:
            d["high"] = list(self.high)
        if self.x0_low is not None:
            d["x0_low"] = list(self.x0_low)
        if self.x0_high is not None:
            d["x0_high"] = list(self.x0_high)
        return d


@dataclass(frozen=True)
class PlannedPolicy:
    """Windows cut from trajectories the simulator plans itself (``{"kind": "planned",
    "windows_per_plan": K}``, PROTOCOL.md §7): not an input draw per window, so only a
    simulator with a planner runs it in its own ``collect`` (the Drake Gen3 simulator,
    ``koopbridge.adapters.drake.windows``); ``collect_windows`` and every other simulator answer
    ``Unsupported``. ``windows_per_plan`` ≥ 1; ``dither`` ≥ 0: ``U(±dither)`` added to every
    planned command (drawn from ``(seed, window)``, clipped to the input bounds), the
    excitation that lets a model tell a command's effect from the state's (without it the
    commands are the planned velocities the arm already moves at)."""

    windows_per_plan: int = 20
    dither: float = 0.0

    def inputs(self, rng: np.random.Generator, T: int, info: SimInfo) -> np.ndarray:
        """Not a per-window input draw: raises ``Unsupported``."""
        raise Unsupported("the planned collect policy needs a simulator that plans its own trajectories (the Drake Gen3 adapter)")

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"kind": "planned", "windows_per_plan": self.windows_per_plan}
        if self.dither > 0:
            d["dither"] = self.dither
        return d

    @staticmethod
    def from_json(d: Mapping[str, Any]) -> PlannedPolicy:
        """``{"kind": "planned", "windows_per_plan": K, "dither": D}`` (K optional, default 20;
        D optional, default 0)."""
        unknown = set(d) - {"kind", "windows_per_plan", "dither"}
        if d.get("kind") != "planned" or unknown:
            raise InvalidInput(f"planned policy: expected kind 'planned', windows_per_plan and dither, got {sorted(d)}")
        k = d.get("windows_per_plan", 20)
        if not isinstance(k, int) or isinstance(k, bool) or k < 1:
            raise InvalidInput(f"planned policy: windows_per_plan must be an integer >= 1, got {k!r}")
        dither = d.get("dither", 0.0)
        if isinstance(dither, bool) or not isinstance(dither, (int, float)) or not (math.isfinite(dither) and dither >= 0):
            raise InvalidInput(f"planned policy: dither must be a finite number >= 0, got {dither!r}")
        return PlannedPolicy(k, float(dither))


@dataclass(frozen=True)
class SimulatorPolicy:
    """A policy the simulator runs itself (a kind of ``SIMULATOR_POLICY_KINDS`` and its settings,
    e.g. ``{"kind": "expert", "windows_per_episode": 50}``): the simulator's own ``collect``
    checks the settings and runs it; ``collect_windows`` and every other simulator answer
    ``Unsupported``."""

    kind: str
    settings: tuple[tuple[str, Any], ...] = ()

    def inputs(self, rng: np.random.Generator, T: int, info: SimInfo) -> np.ndarray:
        """Not a per-window input draw: raises ``Unsupported``."""
        raise Unsupported(f"the {self.kind!r} collect policy needs a simulator that runs it itself (a legged robot with an expert, e.g. the Go2 adapter)")

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, **dict(self.settings)}


def policy_from_json(d: Mapping[str, Any]) -> Policy:
    """The policy a JSON object describes (``{"kind": "uniform", "low": [...], "high": [...]}``,
    a scalar bound applying to every input, ``{"kind": "planned", "windows_per_plan": K}``, or
    a ``SimulatorPolicy`` of a kind in ``SIMULATOR_POLICY_KINDS``)."""
    kind = d.get("kind")
    if kind == "planned":
        return PlannedPolicy.from_json(d)
    if kind in SIMULATOR_POLICY_KINDS:
        return SimulatorPolicy(str(kind), tuple(sorted((str(k), v) for k, v in d.items() if k != "kind")))
    if kind != "uniform":
        kinds = ", ".join(repr(k) for k in SIMULATOR_POLICY_KINDS)
        raise InvalidInput(f"policy kind {kind!r}: only 'uniform' and 'planned' are known (and {kinds} for a simulator that runs them)")
    unknown = set(d) - {"kind", "low", "high", "x0_low", "x0_high"}
    if unknown:
        raise InvalidInput(f"uniform policy: unknown fields {sorted(unknown)}")

    def vec(v: Any) -> tuple[float, ...] | None:
        if v is None:
            return None
        return tuple(float(a) for a in (v if isinstance(v, Sequence) else [v]))

    return UniformPolicy(vec(d.get("low")), vec(d.get("high")), vec(d.get("x0_low")), vec(d.get("x0_high")))


def window_rng(seed: int, index: int) -> np.random.Generator:
    """The generator of window ``index`` of a collection with ``seed``: independent of every
    other window, so a block can be (re)collected on its own."""
    if seed < 0 or index < 0:
        raise InvalidInput(f"seed and window index must be >= 0, got {seed}, {index}")
    return np.random.default_rng([seed, index])


@dataclass
class Windows:
    """A block of windows: ``x`` ``(n, T+1, nx)``, ``u`` ``(n, T, nu)``, windows ``start`` to
    ``start + n - 1`` of the collection with ``seed``; ``reset_seeds[i]`` is the seed window
    ``i`` was reset with (``sim.reset(seed=...)`` reproduces its first state)."""

    x: np.ndarray
    u: np.ndarray
    seed: int
    start: int
    reset_seeds: np.ndarray

    def save_npz(self, path: str | os.PathLike[str]) -> None:
        """Writes ``x`` and ``u`` (the recorder's ``.npz`` layout) plus the block's ``seed``,
        ``start`` and ``reset_seeds``; atomically (temporary file, then rename)."""
        path = os.fspath(path)
        folder = os.path.dirname(os.path.abspath(path))
        fd, tmp = tempfile.mkstemp(prefix=".windows-", suffix=".npz", dir=folder)
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, x=self.x, u=self.u, seed=self.seed, start=self.start, reset_seeds=self.reset_seeds)
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise


@runtime_checkable
class Collector(Protocol):
    """A simulator with its own in-process collection (same results as ``collect_windows``)."""

    def collect(self, policy: Policy, seed: int, n_windows: int, T: int, start: int = 0) -> Windows: ...


def collect_windows(
    sim: Simulator,
    policy: Policy,
    seed: int,
    n_windows: int,
    T: int,
    *,
    start: int = 0,
    step: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Windows:
    """Runs windows ``start .. start + n_windows - 1``: window ``i`` draws a reset seed, (with
    a ``UniformPolicy`` initial-state box) its initial state, and its ``T`` inputs from
    ``window_rng(seed, i)``, resets ``sim`` with that seed (or to that state) and steps it.
    ``step`` replaces ``sim.step`` (a simulator's own unchecked fast path; the inputs are checked
    here once). Any simulator error propagates (the block is then incomplete)."""
    if n_windows < 0 or T < 1:
        raise InvalidInput(f"collect: n_windows must be >= 0 and T >= 1, got {n_windows}, {T}")
    if isinstance(policy, (PlannedPolicy, SimulatorPolicy)):
        policy.inputs(np.random.default_rng(0), T, sim.info())  # raises Unsupported
    info = sim.info()
    box = policy.x0_box(info) if isinstance(policy, UniformPolicy) else None
    step = step or sim.step
    xs = np.empty((n_windows, T + 1, info.nx))
    us = np.empty((n_windows, T, info.nu))
    seeds = np.empty(n_windows, dtype=np.uint64)
    for i in range(n_windows):
        rng = window_rng(seed, start + i)
        reset_seed = int(rng.integers(0, 2**63))
        x0 = None if box is None else rng.uniform(box[0], box[1])
        u = np.asarray(policy.inputs(rng, T, info), dtype=np.float64)
        if u.shape != (T, info.nu) or not np.all(np.isfinite(u)):
            raise InvalidInput(f"collect: the policy gave inputs of shape {u.shape} (or non-finite), expected ({T}, {info.nu})")
        seeds[i] = reset_seed
        us[i] = u
        xs[i, 0] = sim.reset(seed=reset_seed) if x0 is None else sim.reset(x0=x0)
        for t in range(T):
            xs[i, t + 1] = step(u[t])
    return Windows(x=xs, u=us, seed=seed, start=start, reset_seeds=seeds)
