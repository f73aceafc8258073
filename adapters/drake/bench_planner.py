"""Planner figures: solve time per pass (median, p99) and success rate over N random goals, each
planned from the previous reached goal (the first from the upright arm), as a data session does.

    .venv/bin/python adapters/drake/bench_planner.py --goals 300 --seed 1 [--collision-free]

Prints one JSON object (also written to --json FILE when given): per pass the wall and CPU
time of the solved passes (every solver tried counts), success rate, failures by pass, and
plans per second over all goals (failed ones included).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from koopbridge.adapters.drake.plan import Gen3Planner, Infeasible, random_goals


def _stats(v: list[float]) -> dict[str, float]:
    return dict(n=len(v), median=float(np.median(v)), p99=float(np.quantile(v, 0.99)), max=float(np.max(v)))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--goals", type=int, default=300)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--collision-free", action="store_true", help="redraw goals closer than 2 cm to a collision")
    p.add_argument("--solvers", default="snopt,ipopt")
    p.add_argument("--json", help="also write the result here")
    args = p.parse_args()
    planner = Gen3Planner(solvers=args.solvers.split(","))
    goals = random_goals(args.seed, args.goals, planner=planner if args.collision_free else None, margin=0.02)
    times: dict[str, list[float]] = {"kinematic": [], "collision": []}
    cpu: dict[str, list[float]] = {"kinematic": [], "collision": []}
    solvers: dict[str, int] = {}
    failures: dict[str, int] = {}
    start = np.zeros(7)
    ok = 0
    t0, c0 = time.perf_counter(), time.process_time()
    for g in goals:
        try:
            plan = planner.plan(start, g)
        except Infeasible as e:
            failures[e.pass_name] = failures.get(e.pass_name, 0) + 1
            continue
        ok += 1
        for r in plan.passes:
            times[r.name].append(r.solve_time_s)
            cpu[r.name].append(r.cpu_time_s)
            key = f"{r.name}:{r.solver}"
            solvers[key] = solvers.get(key, 0) + 1
        start = plan.goal
    wall, cpu_total = time.perf_counter() - t0, time.process_time() - c0
    out = dict(
        goals=args.goals,
        seed=args.seed,
        collision_free_goals=args.collision_free,
        success=ok,
        success_rate=ok / args.goals,
        failures_by_pass=failures,
        solved_by=solvers,
        wall_s=wall,
        cpu_s=cpu_total,
        plans_per_s=args.goals / wall,
        plans_per_cpu_s=args.goals / cpu_total,
        solve_time_s={k: _stats(v) for k, v in times.items() if v},
        solve_cpu_s={k: _stats(v) for k, v in cpu.items() if v},
    )
    text = json.dumps(out, indent=1)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
