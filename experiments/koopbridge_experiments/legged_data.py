"""A legged robot's expert dataset through its simulator's in-process ``collect`` (the code a Zenoh
``collect`` request runs), robot-agnostic: the robot is named by a ``DataRobot`` (its simulator's
factory and how to describe its expert); ``go2_data`` and ``g1_data`` are the robots' command
lines.

Windows are collected in blocks (``DIR/.blocks/block-NNNNNNN.npz``, each written atomically), so
an interrupted run resumes where it stopped; window ``i`` depends only on ``(policy, seed, i)``.
Episodes of ``--windows-per-episode`` windows never straddle a block or a split (the sizes must
be multiples of it), so train, validation and test come from different episodes. The splits
are ``DIR/{train,val,test}.npz`` for ``koopbridge train --data DIR``, plus ``collect.json``.
"""

from __future__ import annotations

import argparse
import importlib
import json
import multiprocessing
import os
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from .dataset_npz import load_block, save_splits

__all__ = ["DataRobot", "collect_block", "main", "parser", "policy_json"]

_WORKER: dict[str, Any] = {}


@dataclass(frozen=True)
class DataRobot:
    """What the dataset script needs to know of a robot: ``name`` (messages), ``prog`` (the
    command line's name), ``simulator`` (``"module:Class"``, built with ``target_margin=``),
    ``expert`` (a sentence naming the expert and its command box, for the dataset metadata)."""

    name: str
    prog: str
    simulator: str
    expert: str


def _sim(simulator: str, target_margin: float, options: dict[str, Any] | None = None) -> Any:
    """The process's simulator (``"module:Class"`` built with ``target_margin`` and ``options``), reused while they stay the same."""
    kwargs = {"target_margin": target_margin, **(options or {})}
    key = json.dumps([simulator, kwargs], sort_keys=True)
    if key not in _WORKER:
        module, cls = simulator.split(":")
        _WORKER.clear()
        _WORKER[key] = getattr(importlib.import_module(module), cls)(**kwargs)
    return _WORKER[key]


def policy_json(a: argparse.Namespace) -> dict[str, Any]:
    """The collect policy the command line asks for (``expert``, or ``expert+noise`` with ``--noise``)."""
    p: dict[str, Any] = {"kind": "expert+noise", "noise": a.noise} if a.noise > 0 else {"kind": "expert"}
    p.update(windows_per_episode=a.windows_per_episode, push=a.push)
    return p


def collect_block(simulator: str, policy: dict[str, Any], seed: int, start: int, n: int, T: int, path: str,
                  target_margin: float = 0.0, options: dict[str, Any] | None = None) -> tuple[str, float, int]:
    """Collects windows ``start .. start + n - 1`` with the ``simulator`` (``"module:Class"``
    with ``options``, one per process) into the block file ``path`` (atomically); returns the
    path, the seconds spent collecting and the falls (restarts) on the way."""
    from koopbridge.collect import policy_from_json

    sim = _sim(simulator, target_margin, options)
    falls = sim.falls
    t0 = time.perf_counter()
    w = sim.collect(policy_from_json(policy), seed, n, T, start=start)
    dt = time.perf_counter() - t0
    w.save_npz(path)
    return path, dt, sim.falls - falls


def parser(robot: DataRobot, description: str, windows: int = 180_000) -> argparse.ArgumentParser:
    """The command line of ``robot``'s dataset script."""
    p = argparse.ArgumentParser(prog=robot.prog, description=description)
    p.add_argument("--out", required=True, help="output folder (train.npz, val.npz, test.npz + sidecars, collect.json)")
    p.add_argument("--windows", type=int, default=windows, help="total windows (default: %(default)s)")
    p.add_argument("--train", type=int, help="train windows (default: 7/9 of --windows)")
    p.add_argument("--val", type=int, help="validation windows (default: 1/9 of --windows)")
    p.add_argument("--seed", type=int, default=42, help="data seed (default: %(default)s)")
    p.add_argument("--steps", type=int, default=15, help="transitions per window T (default: %(default)s)")
    p.add_argument("--windows-per-episode", type=int, default=50, help="windows cut back to back from one episode (default: %(default)s)")
    p.add_argument("--noise", type=float, default=0.0, help="sigma of Gaussian noise on the expert's targets, rad: 'expert+noise' (default: none)")
    p.add_argument("--push", type=float, default=0.0, help="largest push, m/s, every 4 s at a window boundary (default: none)")
    p.add_argument("--target-margin", type=float, default=0.0, metavar="RAD", help="input bounds = joint ranges widened by RAD "
                   "(the adapter's --target-margin; default: %(default)s, the joint limits)")
    p.add_argument("--block", type=int, default=2000, help="windows per block file, a multiple of --windows-per-episode (default: %(default)s)")
    p.add_argument("--procs", type=int, default=1, help="collecting processes (default: %(default)s)")
    p.add_argument("--keep-blocks", action="store_true", help="keep DIR/.blocks after writing the splits")
    return p


def main(robot: DataRobot, a: argparse.Namespace, options: dict[str, Any] | None = None) -> int:
    """Collects (or resumes) the blocks of ``robot``'s expert data with its simulator built with
    ``options`` (besides ``target_margin``), then writes the three splits; returns the exit code
    (2 for bad sizes). Blocks of another policy, seed, size or options are not reused: the
    options are part of the block folder's name."""
    tag = robot.name
    n_train = a.train if a.train is not None else a.windows * 7 // 9
    n_val = a.val if a.val is not None else a.windows // 9
    n_test = a.windows - n_train - n_val
    K = a.windows_per_episode
    if min(n_train, n_val, n_test) <= 0 or a.steps < 1 or a.block < 1 or a.procs < 1 or K < 1:
        print(f"{tag}: bad sizes train {n_train}, val {n_val}, test {n_test}, T {a.steps}", file=sys.stderr)
        return 2
    if any(v % K for v in (n_train, n_val, a.windows, a.block)):
        print(f"{tag}: train, val, total and block sizes must be multiples of --windows-per-episode {K}", file=sys.stderr)
        return 2
    policy = policy_json(a)
    options = dict(options or {})
    blocks_dir = os.path.join(a.out, ".blocks" + "".join(f"-{k}-{v}" for k, v in sorted(options.items())))
    os.makedirs(blocks_dir, exist_ok=True)
    spec = [(s, min(a.block, a.windows - s), os.path.join(blocks_dir, f"block-{s:07d}.npz")) for s in range(0, a.windows, a.block)]
    todo = sorted((b for b in spec if load_block(b[2], a.seed, b[0], b[1], a.steps) is None), key=lambda b: (b[0] < n_train, b[0]))
    print(f"{tag}: policy {json.dumps(policy)}, simulator options {json.dumps(options)}; {len(spec) - len(todo)} of {len(spec)} blocks present, "
          f"collecting {len(todo)} with {a.procs} process(es)", flush=True)
    t0 = time.perf_counter()
    done = falls = 0

    def report(n: int, fell: int) -> None:
        nonlocal done, falls
        done += n
        falls += fell
        wall = time.perf_counter() - t0
        print(f"{tag}: {done} windows in {wall:.1f} s ({done / wall:.1f} windows/s, {done * a.steps / wall:.0f} steps/s); "
              f"{falls} falls", flush=True)

    args = (robot.simulator, policy, a.seed)
    if a.procs == 1:
        for s, n, path in todo:
            report(n, collect_block(*args, s, n, a.steps, path, a.target_margin, options)[2])
    else:
        # spawn: the workers share nothing with this process (no MuJoCo or onnxruntime state forked).
        with ProcessPoolExecutor(a.procs, mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = [pool.submit(collect_block, *args, s, n, a.steps, path, a.target_margin, options) for s, n, path in todo]
            for f, (_, n, _) in zip(futures, todo, strict=True):
                report(n, f.result()[2])
    wall = time.perf_counter() - t0
    blocks = [load_block(path, a.seed, s, n, a.steps) for s, n, path in spec]
    if any(b is None for b in blocks):
        print(f"{tag}: a block is missing after collection", file=sys.stderr)
        return 1
    x = np.concatenate([b.x for b in blocks if b is not None])
    u = np.concatenate([b.u for b in blocks if b is not None])
    info = _sim(robot.simulator, a.target_margin, options).info()
    cuts = {"train": (0, n_train), "val": (n_train, n_train + n_val), "test": (n_train + n_val, a.windows)}
    save_splits(a.out, x, u, cuts, info, a.seed,
                source=f"{robot.simulator}({json.dumps(options)}) collect (MuJoCo {info.extra['mujoco']['version']}, {info.extra['mujoco']['source']})",
                policy=f"{json.dumps(policy)}: {robot.expert}, {a.windows_per_episode} windows back to back per episode after 1 s of "
                f"warm-up; inputs = the joint targets applied (clipped to the joint ranges widened by {a.target_margin} rad)")
    summary = dict(windows=a.windows, train=n_train, val=n_val, test=n_test, steps=a.steps, seed=a.seed, procs=a.procs, policy=policy,
                   target_margin=a.target_margin, options=options, collected=sum(n for _, n, _ in todo), falls=falls, wall_s=round(wall, 1),
                   windows_per_s=round(sum(n for _, n, _ in todo) / wall, 1) if todo else None)
    with open(os.path.join(a.out, "collect.json"), "w") as f:
        json.dump(summary, f, indent=2)
    print(json.dumps(summary), flush=True)
    if not a.keep_blocks:
        for _, _, path in spec:
            os.unlink(path)
        os.rmdir(blocks_dir)
    return 0


def run(robot: DataRobot, p: argparse.ArgumentParser, argv: Sequence[str] | None = None, options: Sequence[str] = ()) -> int:
    """Parses ``argv`` with ``p`` (``parser`` plus the robot's own options) and runs ``main``
    with the parsed values of ``options`` (argparse destinations) as simulator options."""
    a = p.parse_args(argv)
    return main(robot, a, {k: getattr(a, k) for k in options})
