"""The G1's open-loop replay floor (issue 30): held-out expert references, and each one's recorded
joint targets replayed open loop from its first state on a simulator that has not seen it — the
survival any tracking controller should beat. Survival is the scenario engine's metric
(``koopbridge.survival``: the steps before the first one whose mean joint-position error, over
the state's 21 joints, exceeds the threshold, 0.10 rad for the G1, or whose pelvis has fallen).

    python -m koopbridge_experiments.g1_replay [--references 50] [--steps 200] [--threshold 0.10] [--json FILE]

The references are the expert's, one per episode, under the seed ``legged_robots.REFERENCE_SEED``
(no training episode of ``g1_data``'s seed 42 draws from it): a seeded reset, 1 s of walking
unrecorded, then ``--steps`` recorded steps under random velocity commands over the policy's
ranges changed every 2 s. The replay starts from ``reset(x0)`` of the reference's first state on
a fresh simulator: the 53-D state leaves out the base's x/y, the two wrist rolls and the solver's
warm start, which ``reset(x0)`` places at 0, the default pose at rest and cold — the differences
an open-loop replay cannot correct, as a tracking MPC started the same way must.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from koopbridge import survival

from .legged_robots import REFERENCE_SEED
from .legged_robots import make_references as legged_make_references

__all__ = ["HEIGHT_INDEX", "Q_SLICE", "THRESHOLD", "G1Reference", "fallen_mask", "main", "make_references", "replay"]

#: The G1's 53-D state: joint positions (21), the quaternion, the pelvis height.
Q_SLICE = slice(10, 31)
QUAT_SLICE = slice(0, 4)
HEIGHT_INDEX = 52
#: Survival threshold on the mean joint-position error (rad) for the G1.
THRESHOLD = 0.10


@dataclass(frozen=True)
class G1Reference:
    """One held-out expert rollout: states ``x`` ``(L+1, 53)`` and the applied targets ``u`` ``(L, 23)``."""

    x: np.ndarray
    u: np.ndarray
    index: int


def fallen_mask(x: np.ndarray) -> np.ndarray:
    """Whether each state's pelvis has fallen (``legged.g1.model.FALL``); non-finite rows count as fallen."""
    from koopbridge.adapters.legged.g1.model import FALL

    return np.array([not np.all(np.isfinite(r)) or FALL.fallen(r[QUAT_SLICE], float(r[HEIGHT_INDEX])) for r in np.asarray(x)], dtype=bool)


def make_references(sim: Any, probe: Any, n: int, steps: int, seed: int = REFERENCE_SEED) -> list[G1Reference]:
    """The first ``n`` expert rollouts of ``steps`` transitions (module docstring) collected on
    ``sim`` whose first state the memoryless ``probe`` accepts as ``reset(x0)``: the legged
    robots' ``legged_robots.make_references`` with the G1's expert settings."""
    policy = sim.expert_policy({"kind": "expert", "windows_per_episode": 1, "warmup": 1.0, "command_every": 2.0})
    refs = legged_make_references(n, steps, seed, sim=sim, probe=probe, policy=policy)
    return [G1Reference(x=r.x, u=r.u, index=r.index) for r in refs]


def replay(sim: Any, ref: G1Reference, threshold: float = THRESHOLD) -> tuple[int, np.ndarray]:
    """The reference's targets replayed on ``sim`` from ``reset(x0=ref.x[0])`` until its end or
    a fall; returns (survival, the states)."""
    xs = [np.asarray(sim.reset(x0=ref.x[0]), float)]
    for u in ref.u:
        xs.append(np.asarray(sim.step(u), float))
        if sim.fallen:
            break
    x = np.array(xs)
    joints = list(range(Q_SLICE.start, Q_SLICE.stop))
    return survival(x, ref.x, fallen_mask(x).tolist(), threshold, joints, len(ref.u)), x


def main(argv: Sequence[str] | None = None) -> int:
    """Prints (and with ``--json`` writes) the replay floor over the references; returns the exit code."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.g1_replay", description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--references", type=int, default=50, help="held-out expert references (default: %(default)s)")
    p.add_argument("--steps", type=int, default=200, help="transitions per reference (default: %(default)s)")
    p.add_argument("--threshold", type=float, default=THRESHOLD, help="mean joint-position error that ends survival, rad (default: %(default)s)")
    p.add_argument("--expert", choices=("fastsac", "ppo"), default="fastsac", help="the walking policy (default: %(default)s)")
    p.add_argument("--held", choices=("servo", "locked"), default="servo", help="the adapter's --held (default: %(default)s)")
    p.add_argument("--json", metavar="FILE", help="also write the figures and each reference's floor here")
    a = p.parse_args(argv)
    if a.references < 1 or a.steps < 1 or not a.threshold > 0:
        print("g1_replay: --references and --steps must be >= 1 and --threshold > 0", file=sys.stderr)
        return 2
    from koopbridge.adapters.legged.g1.sim import G1Simulator

    def sim(memory: int = 4096) -> G1Simulator:
        return G1Simulator(policy_name=a.expert, held=a.held, memory=memory, on_fall=None)

    refs = make_references(sim(), sim(0), a.references, a.steps)
    fresh = sim(0)
    floors = np.array([replay(fresh, r, a.threshold)[0] for r in refs])
    out = dict(references=len(refs), steps=a.steps, threshold=a.threshold, expert=a.expert, held=a.held, seed=REFERENCE_SEED,
               mean=float(floors.mean()), std=float(floors.std()), median=float(np.median(floors)), min=int(floors.min()),
               max=int(floors.max()), full_length=int(np.sum(floors == a.steps)), floors=floors.tolist(), indices=[r.index for r in refs])
    print(f"g1_replay: open-loop replay floor over {len(refs)} references of {a.steps} steps at {a.threshold} rad: "
          f"mean {out['mean']:.1f} (std {out['std']:.1f}, median {out['median']:.0f}, min {out['min']}, max {out['max']}; "
          f"{out['full_length']} survive the whole reference)")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
