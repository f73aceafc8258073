"""Prediction windows around a push (issue 44 §3: why the learned feedback loses to EDMD under
pushes): along a legged robot's tracking references the expert's recorded targets are replayed
open loop on an in-process simulator with a push of ``--push`` m/s (direction and step drawn per
reference as the scenario engine's ``perturbation = { push, seed }`` does not: here from
``--seed`` with numpy), and the windows of ``--window`` steps that start ``--after`` steps after
the push are written as a dataset ``.npz``; with ``--push 0`` the same windows of the unpushed
replay. ``koopbridge eval --model DIR --data FILE`` then gives any model's prediction error on
them (EDMD and the neural Koopman model alike), so a model's error after a push can be set
against its error on the same states unpushed (``--per-state``: state by state, raw units). The
push acts while step ``--push-step`` is integrated, so the window of ``--after 0`` starts at the
state before it and its first transition holds the push itself, which no model sees coming: the
first window after the push is ``--after 1``.

    python -m koopbridge_experiments.legged_push_windows --references OUT/references/go2.npz --push 1.0 --out pushed.npz
    python -m koopbridge_experiments.legged_push_windows --references OUT/references/go2.npz --push 0 --out nominal.npz
    koopbridge eval --model OUT/models/go2-survival-go2 --data pushed.npz

A window ends at the first fall (the adapter's fall test): only windows whose every state is
upright are written.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import numpy as np

from .dataset_npz import DatasetMeta, save_dataset_npz
from .legged_robots import ROBOTS


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.legged_push_windows", description=(__doc__ or "").split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robot", choices=sorted(ROBOTS), default="go2", help="the legged robot (default: %(default)s)")
    p.add_argument("--references", required=True, help="a references .npz (legged_references' output)")
    p.add_argument("--push", type=float, required=True, help="push size, m/s (0: no push)")
    p.add_argument("--push-step", type=int, default=40, help="the step of the push (default: %(default)s)")
    p.add_argument("--after", type=int, nargs="+", default=[1, 5, 10, 20],
                   help="window starts after the push step, steps; 0 = the window whose first transition holds the push (default: %(default)s)")
    p.add_argument("--window", type=int, default=15, help="transitions per window (default: %(default)s, the MPC's horizon)")
    p.add_argument("--seed", type=int, default=0, help="seed of the push directions (default: %(default)s)")
    p.add_argument("--out", required=True, help="the dataset .npz to write")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Writes the windows; 2 on bad input."""
    a = parser().parse_args(argv)
    robot = ROBOTS[a.robot]
    if a.push < 0 or not np.isfinite(a.push) or a.window < 1 or a.push_step < 0 or min(a.after) < 0:
        print("legged_push_windows: --push >= 0, --window >= 1, --push-step and --after >= 0", file=sys.stderr)
        return 2
    with np.load(a.references) as z:
        X, U = np.asarray(z["x"], float), np.asarray(z["u"], float)
    sim = robot.simulator(None, 4096)
    info = sim.info()
    lay, fall = robot.layout, robot.fall()
    rng = np.random.default_rng(a.seed)
    xs, us = [], []
    for n in range(len(X)):
        angle = rng.uniform(0, 2 * np.pi)
        pert = {"push": {"step": a.push_step, "velocity": [a.push * np.cos(angle), a.push * np.sin(angle)]}} if a.push > 0 else None
        x = np.asarray(sim.reset(x0=X[n, 0], perturbation=pert) if pert else sim.reset(x0=X[n, 0]), float)
        traj = [x]
        for k in range(U.shape[1]):
            x = np.asarray(sim.step(U[n, k]), float)
            if fall.fallen(x[lay.quat], float(x[lay.height])):
                break
            traj.append(x)
        for d in a.after:
            s = a.push_step + d
            if s + a.window < len(traj):
                xs.append(np.stack(traj[s : s + a.window + 1]))
                us.append(U[n, s : s + a.window])
    if not xs:
        print("legged_push_windows: no window: every replay fell before its windows", file=sys.stderr)
        return 2
    meta = DatasetMeta(env=str(info.get("env", robot.env)), dt=float(info.get("dt", 0.02)), state_names=list(info["state_names"]),
                       input_names=list(info["input_names"]), seed=a.seed, source="koopbridge_experiments.legged_push_windows",
                       policy=f"replay of {a.references}; push {a.push} m/s at step {a.push_step}; windows from {a.after} steps after")
    save_dataset_npz(a.out, np.stack(xs), np.stack(us), meta)
    print(f"legged_push_windows: {len(xs)} windows of {a.window} steps from {len(X)} references -> {a.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
