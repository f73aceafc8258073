"""Tracking of held-out planned Gen3 trajectories in the Drake simulation, in one process: the
planner's open-loop feed-forward (its velocities as commands) against Koopman MPC on a trained
model (``koopbridge.Mpc``, reference = the plan's states over the horizon, input bounds = the
velocity limits). Reports joint RMS and final error per method and the MPC solve time.

    .venv/bin/python adapters/drake/track.py --model runs/kinova --goals 5 --json track.json

Goals are drawn with the seed of split ``test``, session 900 + i of ``drake_collect`` (never a
training session), each planned from the upright arm at rest and held for ``--hold`` s at the end.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import koopbridge
from koopbridge.adapters.drake.collect import goal_seed
from koopbridge.adapters.drake.model import VELOCITY_LIMITS
from koopbridge.adapters.drake.plan import Gen3Planner, Infeasible, random_goals
from koopbridge.adapters.drake.sim import DrakeGen3Sim


def run(sim: DrakeGen3Sim, ref: np.ndarray, ff: np.ndarray, controller) -> tuple[np.ndarray, list[float]]:
    """Executes ``len(ff)`` steps from ``ref[0]``; ``controller(k, x)`` gives the command (None:
    the feed-forward ``ff[k]``). Returns the states and the controller's solve times."""
    x = sim.reset(x0=ref[0])
    xs, times = [x], []
    for k in range(len(ff)):
        if controller is None:
            u = ff[k]
        else:
            u, dt = controller(k, x)
            times.append(dt)
        x = sim.step(np.clip(u, -VELOCITY_LIMITS, VELOCITY_LIMITS))
        xs.append(x)
    return np.array(xs), times


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", required=True, help="a trained model directory (koopbridge train --out)")
    p.add_argument("--goals", type=int, default=5)
    p.add_argument("--seed", type=int, default=42)
    p.add_argument("--horizon", type=int, default=15)
    p.add_argument("--hold", type=float, default=0.2, help="seconds held at the goal after the plan")
    p.add_argument("--json", help="also write the result here")
    args = p.parse_args()
    sim, planner = DrakeGen3Sim(), Gen3Planner()
    mpc = koopbridge.Mpc(args.model, horizon=args.horizon, u_min=(-VELOCITY_LIMITS).tolist(), u_max=VELOCITY_LIMITS.tolist())
    rows = []
    for i in range(args.goals):
        goal = random_goals(goal_seed(args.seed, "test", 900 + i), 1, planner=planner, margin=0.02)[0]
        try:
            plan = planner.plan(np.zeros(7), goal)
        except Infeasible as e:
            rows.append(dict(goal=goal.tolist(), error=str(e)))
            continue
        _, q, qd = plan.sample(sim.dt)
        hold = int(round(args.hold / sim.dt))
        ref = np.concatenate([np.hstack([q, qd]), np.tile(np.r_[q[-1], np.zeros(7)], (hold, 1))])
        ff = np.concatenate([qd[:-1], np.zeros((hold, 7))])

        def koopman(k: int, x: np.ndarray) -> tuple[np.ndarray, float]:
            r = ref[np.minimum(np.arange(k + 1, k + 1 + args.horizon), len(ref) - 1)]
            sol = mpc.solve(x, r)
            return sol["u"][0], sol["solve_time"]

        row: dict = dict(goal=goal.tolist(), duration=plan.duration, steps=len(ff))
        for name, ctrl in (("feed-forward", None), ("koopman-mpc", koopman)):
            t0 = time.perf_counter()
            xs, times = run(sim, ref, ff, ctrl)
            err = xs[:, :7] - ref[:, :7]
            row[name] = dict(
                rms_rad=float(np.sqrt(np.mean(err**2))),
                final_rad=float(np.max(np.abs(err[-1]))),
                wall_s=time.perf_counter() - t0,
                **({"solve_ms_median": 1e3 * float(np.median(times)), "solve_ms_p99": 1e3 * float(np.quantile(times, 0.99))} if times else {}),
            )
        rows.append(row)
        print(json.dumps(row), flush=True)
    ok = [r for r in rows if "error" not in r]
    summary = {
        name: dict(
            rms_rad_mean=float(np.mean([r[name]["rms_rad"] for r in ok])),
            final_rad_mean=float(np.mean([r[name]["final_rad"] for r in ok])),
        )
        for name in ("feed-forward", "koopman-mpc")
    } if ok else {}
    out = dict(model=args.model, goals=args.goals, seed=args.seed, horizon=args.horizon, summary=summary, rows=rows)
    print(json.dumps(out["summary"], indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
