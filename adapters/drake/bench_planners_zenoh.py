"""Planner throughput over Zenoh: plans per second with P planner processes
(`python -m koopbridge.adapters.drake_planner`, ids p0..p{P-1}) serving one client. Every run
plans the same problems: goal i from goal i-1 (a data session's chain; goal 0 from the upright
arm), from one queue: each planner is asked the next problem as soon as it has answered.

    .venv/bin/python adapters/drake/bench_planners_zenoh.py --goals 60 --procs 1,2

Prints one line per P and, with --json FILE, the figures as JSON: plans, infeasible goals,
wall time, plans per second, and the speed-up against the first P given.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from koopbridge import BridgeTimeout, Client, RemoteError
from koopbridge.adapters.drake.plan import Gen3Planner, random_goals


def _free_endpoint() -> str:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _ask(c: Client, key: str, start: list[float], goal: list[float], dt: float, ready_s: float = 0.0) -> dict | None:
    """One plan, or None when the planner answered `infeasible`; while `ready_s` lasts, a query
    that found no planner yet is asked again."""
    body = json.dumps(dict(start=start, goal=goal, dt=dt)).encode()
    until = time.monotonic() + ready_s
    while True:
        try:
            return json.loads(c.query(key, body, timeout=120.0))
        except RemoteError as e:
            if e.code == "infeasible":
                return None
            raise
        except BridgeTimeout:
            if time.monotonic() > until:
                raise
            time.sleep(0.2)


def run(procs: int, goals: list[list[float]], dt: float, log_dir: Path) -> dict:
    """Plans the problems (goal i-1 -> goal i) of `goals` on `procs` planner processes at once."""
    session = f"bench-planners-{procs}-{int(time.time())}"
    ep = _free_endpoint()
    children = []
    for i in range(procs):
        cmd = [sys.executable, "-m", "koopbridge.adapters.drake_planner", "--session", session, "--id", f"p{i}"]
        cmd += ["--listen", ep] if i == 0 else ["--connect", ep]
        log = open(log_dir / f"planner-{procs}-{i}.log", "w")
        children.append((subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT), log))
    try:
        with Client(session=session, connect=[ep]) as c:
            home = [0.0] * 7
            for i in range(procs):  # each planner up (one plan each, not timed)
                _ask(c, f"planner/p{i}/plan", home, [0.1] * 7, dt, ready_s=120.0)
            problems = list(zip([home, *goals[:-1]], goals, strict=True))
            queue = list(reversed(list(enumerate(problems))))
            lock = threading.Lock()
            done: list[list[bool]] = [[] for _ in range(procs)]
            seconds: list[float] = []
            longest: list[tuple[float, int, bool]] = [(0.0, -1, True)]
            errors: list[BaseException] = []

            def chain(i: int) -> None:
                try:
                    while True:
                        with lock:
                            if not queue:
                                return
                            k, (start, goal) = queue.pop()
                        t = time.monotonic()
                        ok = _ask(c, f"planner/p{i}/plan", start, goal, dt) is not None
                        dt_k = time.monotonic() - t
                        with lock:
                            done[i].append(ok)
                            seconds.append(dt_k)
                            longest[0] = max(longest[0], (dt_k, k, ok))
                except BaseException as e:  # noqa: BLE001 - reported after the join
                    errors.append(e)

            t0 = time.monotonic()
            threads = [threading.Thread(target=chain, args=(i,)) for i in range(procs)]
            for th in threads:
                th.start()
            for th in threads:
                th.join()
            wall = time.monotonic() - t0
            if errors:
                raise errors[0]
    finally:
        for p, log in children:
            p.terminate()
            p.wait(timeout=30)
            log.close()
    solved = sum(sum(d) for d in done)
    seconds.sort()
    return dict(procs=procs, goals=len(goals), plans=solved, infeasible=len(goals) - solved, wall_s=wall, plans_per_s=len(goals) / wall,
                plan_s_median=seconds[len(seconds) // 2], plan_s_max=seconds[-1], plan_s_sum=sum(seconds),
                longest_problem=longest[0][1], longest_solved=longest[0][2])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--goals", type=int, default=60)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--procs", default="1,2", help="planner process counts, in the order run (default: %(default)s)")
    p.add_argument("--dt", type=float, default=0.001, help="sampling period of the replies [s] (default: %(default)s)")
    p.add_argument("--json", help="also write the result here")
    a = p.parse_args()
    goals = [list(map(float, g)) for g in random_goals(a.seed, a.goals, planner=Gen3Planner(), margin=0.02)]
    out = []
    with tempfile.TemporaryDirectory() as d:
        for n in (int(x) for x in a.procs.split(",")):
            r = run(n, goals, a.dt, Path(d))
            r["speedup"] = r["plans_per_s"] / out[0]["plans_per_s"] if out else 1.0
            out.append(r)
            print(f"{n} planner(s): {r['goals']} goals ({r['infeasible']} infeasible) in {r['wall_s']:.1f} s = {r['plans_per_s']:.2f} plans/s, {r['speedup']:.2f}x; "
                  f"per plan (request to reply) median {r['plan_s_median']:.3f} s, longest {r['plan_s_max']:.1f} s (problem {r['longest_problem']}, solved {r['longest_solved']}), sum {r['plan_s_sum']:.1f} s", flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
