"""Writes a legged robot's held-out expert references as a tracking task's ``references`` file
(``[control] references = "FILE.npz"`` in a scenario: ``x`` (N, T+1, nx), ``u`` (N, T, nu), the
dataset layout with its metadata), so that the scenario engine tracks them:

    python -m koopbridge_experiments.legged_references --robot go2 --references 50 --steps 300 --out refs.npz

The references are ``legged_robots.references``: expert rollouts under velocity commands the
training data never saw (seed 90042 by default), each starting in a state the adapter accepts.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .dataset_npz import DatasetMeta, save_dataset_npz
from .legged_robots import REFERENCE_SEED, ROBOTS, references


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.legged_references", description=(__doc__ or "").split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robot", choices=sorted(ROBOTS), required=True, help="the legged robot")
    p.add_argument("--references", type=int, default=50, help="how many references (default: %(default)s)")
    p.add_argument("--steps", type=int, help="transitions per reference (default: the robot's survival cap: Go2 300, G1 200)")
    p.add_argument("--seed", type=int, default=REFERENCE_SEED, help="seed of the references (default: %(default)s; the expert data use 42)")
    p.add_argument("--out", required=True, help="the .npz to write (its folder is created)")
    p.add_argument("--held", choices=("servo", "locked"), default="locked", help="G1 only: the adapter's --held (default: %(default)s)")
    p.add_argument("--expert", choices=("fastsac", "ppo"), default="fastsac", help="G1 only: the walking policy (default: %(default)s)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Writes the references; returns the exit code (2: bad arguments)."""
    a = parser().parse_args(argv)
    robot = ROBOTS[a.robot]
    steps = a.steps if a.steps is not None else robot.steps
    if a.references < 1 or steps < 1:
        print("legged_references: --references and --steps must be >= 1", file=sys.stderr)
        return 2
    skipped: list[dict[str, object]] = []
    refs = references(robot, a.references, steps, a.seed, a, skipped)
    sim = robot.simulator(a, 0)
    info = sim.info() if callable(getattr(sim, "info", None)) else {}
    x = np.stack([r.x for r in refs])
    u = np.stack([r.u for r in refs])
    meta = DatasetMeta(env=str(info.get("env", robot.env)), dt=float(info.get("dt", 0.02)),
                       state_names=list(info.get("state_names", [f"x{i}" for i in range(x.shape[2])])),
                       input_names=list(info.get("input_names", [f"u{i}" for i in range(u.shape[2])])), seed=a.seed,
                       source="koopbridge_experiments.legged_references", policy=robot.held_out.format(seed=a.seed) +
                       f"; rollouts {[r.index for r in refs]}" + (f"; skipped {json.dumps(skipped)}" if skipped else ""))
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    save_dataset_npz(a.out, x, u, meta)
    print(f"legged_references: {len(refs)} {robot.title} references of {steps} steps -> {a.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
