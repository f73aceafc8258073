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
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..._native import KoopbridgeError
from .plan import Gen3Planner, random_goals
from .sim import DrakeGen3Sim

__all__ = ["SPLITS", "collect_session", "goal_seed", "main", "write_dataset"]

SPLITS = {"train": 0, "val": 1, "test": 2}


def goal_seed(seed: int, split: str, session: int) -> int:
    """The goal seed of one session: distinct for every (seed, split, session)."""
    return int(np.random.SeedSequence([seed, SPLITS[split], session]).generate_state(1, np.uint64)[0])


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.ascontiguousarray(a, dtype="<f8"), version=(1, 0))
    return buf.getvalue()


def write_dataset(path: str, x: np.ndarray, u: np.ndarray, meta: dict[str, Any], plan: np.ndarray | None = None, session: np.ndarray | None = None) -> None:
    """Writes ``x``, ``u`` and ``meta`` (plus n, steps, nx, nu) as a koopbridge ``.npz`` and its
    sidecar ``.json``, each to a temporary file in the same folder renamed into place; ``plan``
    (which goal each window executes) goes in as the member ``plan.npy``, ``session`` (which
    session) as ``session.npy``."""
    n, t1, nx = x.shape
    full = dict(n=n, steps=t1 - 1, nx=nx, nu=u.shape[2], **meta)
    text = json.dumps(full, indent=1, allow_nan=False).encode()
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    for target, write in (
        (path, lambda f: _zip(f, x, u, text, {"plan": plan, "session": session})),
        (os.path.splitext(path)[0] + ".json", lambda f: f.write(text)),
    ):
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=folder)
        try:
            with os.fdopen(fd, "wb") as f:
                write(f)
                f.flush()
                os.fsync(f.fileno())
            os.chmod(tmp, 0o644)  # mkstemp makes it private; a dataset is for everyone to read
            os.replace(tmp, target)
        except BaseException:
            os.unlink(tmp)
            raise


def _zip(f: Any, x: np.ndarray, u: np.ndarray, meta: bytes, extra: dict[str, np.ndarray | None]) -> None:
    with zipfile.ZipFile(f, "w", zipfile.ZIP_STORED) as z:
        z.writestr("x.npy", _npy(x))
        z.writestr("u.npy", _npy(u))
        for name, a in extra.items():
            if a is not None:
                z.writestr(f"{name}.npy", _npy(a))
        z.writestr("meta.json", meta)


def combine(folder: str, split: str, max_windows: int | None = None) -> tuple[str, int]:
    """Writes ``{folder}/{split}.npz`` (the name ``koopbridge train --data`` reads) from every
    ``{split}-NNN.npz`` session there: windows shuffled across sessions (seeded by their goal
    seeds), at most ``max_windows`` of them; the metadata list each session's goals and seeds.
    Returns the path and the number of windows."""
    import glob

    paths = sorted(glob.glob(os.path.join(folder, f"{split}-[0-9][0-9][0-9].npz")))
    if not paths:
        raise KoopbridgeError(f"no {split}-NNN.npz sessions in {folder}")
    xs, us, plans, sessions, metas = [], [], [], [], []
    for p in paths:
        with zipfile.ZipFile(p) as z:
            m = json.loads(z.read("meta.json"))
            xs.append(np.load(z.open("x.npy")))
            us.append(np.load(z.open("u.npy")))
            plans.append(np.load(z.open("plan.npy")))
        sessions.append(np.full(len(plans[-1]), float(m["session"])))
        metas.append(m)
    order = np.random.default_rng([m["goal_seed"] for m in metas]).permutation(sum(len(a) for a in plans))
    order = order[: max_windows if max_windows is not None else len(order)]
    keep = {k: metas[0][k] for k in ("env", "dt", "state_names", "input_names", "pairing", "source", "policy", "split", "base_seed", "goal_margin_m", "planner")}
    meta = dict(
        keep,
        seed=metas[0]["base_seed"],
        shuffled=True,
        sessions=[dict(session=m["session"], goal_seed=m["goal_seed"], goals=m["goals"], failed_goals=m["failed_goals"], windows=m["n"]) for m in metas],
    )
    out = os.path.join(folder, f"{split}.npz")
    cat = lambda parts: np.concatenate(parts)[order]  # noqa: E731
    write_dataset(out, cat(xs), cat(us), meta, cat(plans), cat(sessions))
    return out, len(order)


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
    p.add_argument("--combine", action="store_true", help="then write {split}.npz from all {split}-NNN.npz sessions in --out (--sessions 0: only that)")
    p.add_argument("--max-windows", type=int, help="with --combine: keep at most this many windows (e.g. 140000 / 20000)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the collection; returns the exit code."""
    args = parser().parse_args(argv)
    if args.sessions < (0 if args.combine else 1) or args.goals < 1 or args.steps < 1:
        print("error: --sessions (unless --combine), --goals and --steps must be at least 1", file=sys.stderr)
        return 2
    try:
        planner = Gen3Planner() if args.sessions else None
        sim = DrakeGen3Sim() if args.sessions else None
        for s in range(args.first_session, args.first_session + args.sessions):
            x, u, plan, meta = collect_session(sim, planner, args.seed, args.split, s, args.goals, args.steps, args.goal_margin, log=sys.stderr)
            path = os.path.join(args.out, f"{args.split}-{s:03d}.npz")
            write_dataset(path, x, u, meta, plan, np.full(len(plan), float(s)))
            print(f"{path}: {x.shape[0]} windows from {args.goals - len(meta['failed_goals'])}/{args.goals} plans ({meta['wall_s']:.1f} s)", file=sys.stderr, flush=True)
        if args.combine:
            path, n = combine(args.out, args.split, args.max_windows)
            print(f"{path}: {n} windows", file=sys.stderr)
    except KoopbridgeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
