"""Kinova Gen3 data per SPEC ("Kinova data", strategy "constrained, expert-guided"): collection
sessions of random joint-space goals, each planned (two passes) and executed in the Drake
simulation, logged at 1 kHz and cut into windows of T = 15, written as koopbridge datasets.

    python -m koopbridge.adapters.drake_collect --out data/kinova --split train --sessions 3

Each session writes ``{out}/{split}-{session:03d}.npz`` (members ``x.npy [n, T+1, 14]``,
``u.npy [n, T, 7]``, ``meta.json``; the trainer reads it) and the sidecar ``.json``, atomically.
The metadata name the goals, the goal seed, the planner's settings and each plan's solver and
status. Goal seeds differ per split and session, so test goals are never training goals.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
import tempfile
import time
import zipfile
from typing import Any, Sequence

import numpy as np

from .._native import KoopbridgeError
from .drake_plan import Gen3Planner, random_goals
from .drake_sim import DrakeGen3Sim

__all__ = ["SPLITS", "collect_session", "goal_seed", "main", "write_dataset"]

SPLITS = {"train": 0, "val": 1, "test": 2}


def goal_seed(seed: int, split: str, session: int) -> int:
    """The goal seed of one session: distinct for every (seed, split, session)."""
    return int(np.random.SeedSequence([seed, SPLITS[split], session]).generate_state(1, np.uint64)[0])


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.ascontiguousarray(a, dtype="<f8"), version=(1, 0))
    return buf.getvalue()


def write_dataset(path: str, x: np.ndarray, u: np.ndarray, meta: dict[str, Any], plan: np.ndarray | None = None) -> None:
    """Writes ``x``, ``u`` and ``meta`` (plus n, steps, nx, nu) as a koopbridge ``.npz`` and its
    sidecar ``.json``, each to a temporary file in the same folder renamed into place; ``plan``
    (which goal each window executes) goes in as the member ``plan.npy``."""
    n, t1, nx = x.shape
    full = dict(n=n, steps=t1 - 1, nx=nx, nu=u.shape[2], **meta)
    text = json.dumps(full, indent=1, allow_nan=False).encode()
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    for target, write in (
        (path, lambda f: _zip(f, x, u, text, plan)),
        (os.path.splitext(path)[0] + ".json", lambda f: f.write(text)),
    ):
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=folder)
        try:
            with os.fdopen(fd, "wb") as f:
                write(f)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, target)
        except BaseException:
            os.unlink(tmp)
            raise


def _zip(f: Any, x: np.ndarray, u: np.ndarray, meta: bytes, plan: np.ndarray | None) -> None:
    with zipfile.ZipFile(f, "w", zipfile.ZIP_STORED) as z:
        z.writestr("x.npy", _npy(x))
        z.writestr("u.npy", _npy(u))
        if plan is not None:
            z.writestr("plan.npy", _npy(plan))
        z.writestr("meta.json", meta)


def collect_session(sim: DrakeGen3Sim, planner: Gen3Planner, seed: int, split: str, session: int, goals: int, steps: int, margin: float, log: Any = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """One session: ``goals`` collision-free random goals (drawn with ``goal_seed``), executed
    one after the other from the upright arm. Returns ``x``, ``u``, the goal index of each window
    and the metadata; the windows are shuffled (seeded by the goal seed), so that the first m
    windows of a file come from the whole session."""
    gs = goal_seed(seed, split, session)
    targets = random_goals(gs, goals, planner=planner, margin=margin)
    t0 = time.perf_counter()

    def progress(i: int, rec: dict[str, Any]) -> None:
        if log is not None and ((i + 1) % 25 == 0 or i + 1 == goals):
            print(f"{split} session {session}: {i + 1}/{goals} goals, {time.perf_counter() - t0:.1f} s", file=log, flush=True)

    out = sim.collect_plans(planner, targets, steps=steps, on_plan=progress)
    plan_of = np.concatenate([np.full(p.get("windows", 0), i, float) for i, p in enumerate(out["plans"])] + [np.zeros(0)])
    order = np.random.default_rng(gs).permutation(len(plan_of))
    info = sim.info()
    failed = [i for i, p in enumerate(out["plans"]) if "error" in p]
    meta = dict(
        env=info["env"],
        dt=info["dt"],
        state_names=info["state_names"],
        input_names=info["input_names"],
        pairing="aligned",
        seed=gs,
        source=f"drake:{info['version']}",
        policy="trajopt-expert",
        shuffled=True,
        split=split,
        session=session,
        base_seed=seed,
        goal_seed=gs,
        goals=targets.tolist(),
        goal_margin_m=margin,
        planner=dict(
            method="KinematicTrajectoryOptimization, two passes (kinematic, collision)",
            control_points=planner.num_control_points,
            duration_s=[planner.min_duration, planner.max_duration],
            min_distance_m=planner.min_distance_bound,
            collision_samples=planner.collision_samples,
            solvers=[s for s, _ in planner.solvers],
        ),
        plans=out["plans"],
        failed_goals=failed,
        wall_s=time.perf_counter() - t0,
    )
    return out["x"][order], out["u"][order], plan_of[order], meta


def parser() -> argparse.ArgumentParser:
    """The command-line parser of the collection script."""
    p = argparse.ArgumentParser(prog="python -m koopbridge.adapters.drake_collect", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--split", choices=list(SPLITS), default="train", help="which split (its goals never appear in the others; default: %(default)s)")
    p.add_argument("--sessions", type=int, default=1, help="collection sessions (default: %(default)s)")
    p.add_argument("--first-session", type=int, default=0, help="index of the first session (to add sessions later; default: %(default)s)")
    p.add_argument("--goals", type=int, default=300, help="goals per session (SPEC: 300; default: %(default)s)")
    p.add_argument("--steps", type=int, default=15, help="transitions per window T (default: %(default)s)")
    p.add_argument("--seed", type=int, default=42, help="base seed (default: %(default)s)")
    p.add_argument("--goal-margin", type=float, default=0.02, help="goals closer than this to a collision are redrawn [m] (default: %(default)s)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the collection; returns the exit code."""
    args = parser().parse_args(argv)
    if args.sessions < 1 or args.goals < 1 or args.steps < 1:
        print("error: --sessions, --goals and --steps must be at least 1", file=sys.stderr)
        return 2
    try:
        planner = Gen3Planner()
        sim = DrakeGen3Sim()
        for s in range(args.first_session, args.first_session + args.sessions):
            x, u, plan, meta = collect_session(sim, planner, args.seed, args.split, s, args.goals, args.steps, args.goal_margin, log=sys.stderr)
            path = os.path.join(args.out, f"{args.split}-{s:03d}.npz")
            write_dataset(path, x, u, meta, plan)
            print(f"{path}: {x.shape[0]} windows from {args.goals - len(meta['failed_goals'])}/{args.goals} plans ({meta['wall_s']:.1f} s)", file=sys.stderr, flush=True)
    except KoopbridgeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
