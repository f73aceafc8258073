"""The Franka Panda's SPEC dataset through the MuJoCo simulator's in-process ``collect``: home +
U(±0.2) starts, U(±0.12) commands every step, data seed 42, T = 15, windows split 140k/20k/20k,
written as ``DIR/{train,val,test}.npz`` for ``koopbridge train --data DIR``.

    python -m koopbridge_experiments.franka_data --windows 180000 --out data/franka-aligned [--procs 2]

Windows are collected in blocks (``DIR/.blocks/block-NNNNNN.npz``, each written atomically), so
an interrupted run resumes where it stopped; window ``i`` depends only on ``(seed, i)``. Windows
are independent draws, so the split is by index: the first ``train`` windows, then ``val``,
then ``test`` (statistically the same as SPEC's shuffle of one pool).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from koopbridge.collect import UniformPolicy

from .dataset_npz import load_block, save_splits

__all__ = ["collect_block", "main", "parser"]

#: SPEC's data commands: U(±0.12) rad/s every step.
COMMAND_RANGE = 0.12


def _sim(state: str):  # type: ignore[no-untyped-def]
    from koopbridge.adapters.mujoco.sim import FrankaSimulator

    return FrankaSimulator(state=state)


_WORKER_SIM = None


def collect_block(state: str, seed: int, start: int, n: int, T: int, path: str) -> tuple[str, float]:
    """Collects windows ``start .. start + n - 1`` into the block file ``path`` (atomically);
    returns the path and the seconds spent collecting (model build excluded)."""
    global _WORKER_SIM
    if _WORKER_SIM is None or _WORKER_SIM.state_layout != state:
        _WORKER_SIM = _sim(state)
    policy = UniformPolicy((-COMMAND_RANGE,), (COMMAND_RANGE,))
    t0 = time.perf_counter()
    w = _WORKER_SIM.collect(policy, seed, n, T, start=start)
    dt = time.perf_counter() - t0
    w.save_npz(path)
    return path, dt


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m koopbridge_experiments.franka_data``."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.franka_data", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="output folder (train.npz, val.npz, test.npz + sidecars)")
    p.add_argument("--windows", type=int, default=180_000, help="total windows (default: %(default)s)")
    p.add_argument("--train", type=int, help="train windows (default: 7/9 of --windows)")
    p.add_argument("--val", type=int, help="validation windows (default: 1/9 of --windows)")
    p.add_argument("--seed", type=int, default=42, help="data seed (default: %(default)s)")
    p.add_argument("--steps", type=int, default=15, help="transitions per window T (default: %(default)s)")
    p.add_argument("--state", default="ee,q,qd", choices=("ee,q,qd", "q,qd"), help="state layout (default: %(default)s)")
    p.add_argument("--block", type=int, default=2000, help="windows per block file (default: %(default)s)")
    p.add_argument("--procs", type=int, default=1, help="collecting processes (default: %(default)s)")
    p.add_argument("--keep-blocks", action="store_true", help="keep DIR/.blocks after writing the splits")
    p.add_argument("--from-blocks", metavar="BLOCKS", help="collect nothing: write the splits from the blocks already in "
                   "BLOCKS (another run's OUT/.blocks, possibly still running); train is the prefix of train windows present")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Collects (or resumes) the blocks, then writes the three splits; returns the exit code."""
    a = parser().parse_args(argv)
    n_train = a.train if a.train is not None else a.windows * 7 // 9
    n_val = a.val if a.val is not None else a.windows // 9
    n_test = a.windows - n_train - n_val
    if min(n_train, n_val, n_test) <= 0 or a.steps < 1 or a.block < 1 or a.procs < 1:
        print(f"franka_data: bad sizes train {n_train}, val {n_val}, test {n_test}, T {a.steps}", file=sys.stderr)
        return 2
    blocks_dir = a.from_blocks or os.path.join(a.out, ".blocks")
    os.makedirs(blocks_dir, exist_ok=True)
    os.makedirs(a.out, exist_ok=True)
    starts = list(range(0, a.windows, a.block))
    spec = [(s, min(a.block, a.windows - s), os.path.join(blocks_dir, f"block-{s:07d}.npz")) for s in starts]
    # Validation and test blocks first, so that a partial run (--from-blocks) can already train.
    todo = sorted((b for b in spec if load_block(b[2], a.seed, b[0], b[1], a.steps) is None), key=lambda b: (b[0] < n_train, b[0]))
    if a.from_blocks:
        return _write_partial(a, spec, n_train)
    print(f"franka_data: {len(spec) - len(todo)} of {len(spec)} blocks present, collecting {len(todo)} with {a.procs} process(es)", flush=True)
    t0 = time.perf_counter()
    busy = 0.0
    done = 0
    def report(n: int, seconds: float) -> None:
        nonlocal busy, done
        busy += seconds
        done += n
        wall = time.perf_counter() - t0
        print(f"franka_data: {done} windows in {wall:.1f} s ({done / wall:.1f} windows/s)", flush=True)

    if a.procs == 1:
        for s, n, path in todo:
            report(n, collect_block(a.state, a.seed, s, n, a.steps, path)[1])
    else:
        # spawn: the workers share nothing with this process (no Zenoh or MuJoCo state forked).
        with ProcessPoolExecutor(a.procs, mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = [pool.submit(collect_block, a.state, a.seed, s, n, a.steps, path) for s, n, path in todo]
            for f, (_, n, _) in zip(futures, todo, strict=True):
                report(n, f.result()[1])
    wall = time.perf_counter() - t0
    blocks = [load_block(path, a.seed, s, n, a.steps) for s, n, path in spec]
    if any(b is None for b in blocks):
        print("franka_data: a block is missing after collection", file=sys.stderr)
        return 1
    x = np.concatenate([b.x for b in blocks if b is not None])
    u = np.concatenate([b.u for b in blocks if b is not None])
    _write_splits(a, x, u, {"train": (0, n_train), "val": (n_train, n_train + n_val), "test": (n_train + n_val, a.windows)})
    summary = dict(windows=a.windows, train=n_train, val=n_val, test=n_test, steps=a.steps, seed=a.seed, procs=a.procs,
                   collected=sum(n for _, n, _ in todo), wall_s=round(wall, 2), collect_s=round(busy, 2),
                   windows_per_s=round(sum(n for _, n, _ in todo) / wall, 1) if todo else None)
    print(json.dumps(summary), flush=True)
    if not a.keep_blocks:
        for _, _, path in spec:
            os.unlink(path)
        os.rmdir(blocks_dir)
    return 0


def _write_splits(a: argparse.Namespace, x: np.ndarray, u: np.ndarray, cuts: dict[str, tuple[int, int]]) -> None:
    """Writes ``OUT/{name}.npz`` for each ``name: (lo, hi)`` window range of ``x``/``u``."""
    info = _sim(a.state).info()
    import mujoco

    save_splits(a.out, x, u, cuts, info, a.seed,
                source=f"koopbridge.adapters.mujoco.sim collect (MuJoCo {mujoco.__version__}, {os.path.basename(info.extra['mujoco']['model_file'])})",
                policy=f"uniform random input U(±{COMMAND_RANGE}) each step; reset home + U(±0.2) clipped to the joint limits")


def _write_partial(a: argparse.Namespace, spec: list[tuple[int, int, str]], n_train: int) -> int:
    """``--from-blocks``: the splits from the blocks present (all validation and test blocks,
    the prefix of the train blocks)."""
    blocks = [load_block(path, a.seed, s, n, a.steps) for s, n, path in spec]
    held = [b for (s, _, _), b in zip(spec, blocks, strict=False) if s >= n_train]
    if any(b is None for b in held):
        print("franka_data: --from-blocks needs every validation and test block", file=sys.stderr)
        return 1
    train = []
    for (s, _, _), b in zip(spec, blocks, strict=False):
        if s >= n_train or b is None:
            break
        train.append(b)
    if not train:
        print("franka_data: --from-blocks found no train block", file=sys.stderr)
        return 1
    m = sum(b.x.shape[0] for b in train)
    x = np.concatenate([b.x for b in train + held])  # type: ignore[union-attr]
    u = np.concatenate([b.u for b in train + held])  # type: ignore[union-attr]
    n_val = a.val if a.val is not None else a.windows // 9
    _write_splits(a, x, u, {"train": (0, m), "val": (m, m + n_val), "test": (m + n_val, len(x))})
    print(json.dumps(dict(train=m, val=n_val, test=len(x) - m - n_val, from_blocks=a.from_blocks)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
