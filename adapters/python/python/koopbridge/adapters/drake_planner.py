"""The Drake Gen3 planner as a koopbridge participant: ``…/planner/{id}/plan`` answered by the
two-pass trajectory optimisation of ``drake_plan``, served by the Rust ``PlannerService``.

    python -m koopbridge.adapters.drake_planner --session S --id planner0

Request JSON ``{"start": [7], "goal": [7], "dt": s}``; reply JSON ``{"t": [n], "q": [n][7],
"qd": [n][7], "duration", "dt", "passes": [{"name", "solver", "status", "solve_time_s",
"cost"}]}``. Errors: ``infeasible`` (naming the pass and the solvers' statuses), ``bad_request``
(bad JSON, NaN, out-of-limits configuration, bad dt), ``dimension``, ``busy`` (a plan is running).
"""

from __future__ import annotations

import argparse
import sys
import threading
from typing import Any, Sequence

from .._native import KoopbridgeError, PlannerService
from ..serve_args import _lifeline
from .drake_plan import Gen3Planner

__all__ = ["handler", "main", "parser"]


def handler(planner: Gen3Planner) -> Any:
    """The ``plan(start, goal, dt) -> dict`` callable that ``PlannerService`` serves."""

    def plan(start: list[float], goal: list[float], dt: float) -> dict[str, Any]:
        p = planner.plan(start, goal)
        t, q, qd = p.sample(dt)
        return dict(
            t=t.tolist(),
            q=q.tolist(),
            qd=qd.tolist(),
            duration=p.duration,
            dt=dt,
            passes=[dict(name=r.name, solver=r.solver, status=r.status, solve_time_s=r.solve_time_s, cost=r.cost) for r in p.passes],
        )

    return plan


def parser() -> argparse.ArgumentParser:
    """The command-line parser of the planner service."""
    p = argparse.ArgumentParser(
        prog="python -m koopbridge.adapters.drake_planner",
        description="Serve the two-pass Drake trajectory optimisation of the Kinova Gen3 at koopbridge/{session}/planner/{id}/plan.",
    )
    p.add_argument("--min-distance", type=float, default=0.01, help="clearance of the collision pass [m] (default: %(default)s)")
    p.add_argument("--solvers", default="snopt,ipopt", help="solvers in the order tried (default: %(default)s)")
    p.add_argument("--table-z", type=float, default=0.0, help="height of the table top [m] (default: %(default)s)")
    g = p.add_argument_group("serving (koopbridge protocol over Zenoh)")
    g.add_argument("--session", default="default", help="koopbridge session id (default: %(default)s)")
    g.add_argument("--id", default="planner0", help="planner id: key koopbridge/{session}/planner/{id}/plan (default: %(default)s)")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="Zenoh endpoint to connect to (repeatable)")
    g.add_argument("--listen", action="append", default=[], metavar="ENDPOINT", help="Zenoh endpoint to listen on (repeatable)")
    g.add_argument("--mode", choices=["peer", "client", "router"], default="peer", help="Zenoh mode (default: %(default)s)")
    g.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 configuration file")
    g.add_argument("--stdin-lifeline", action="store_true", help="stop serving when standard input closes (used by `koopbridge run`)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the planner service; returns the exit code."""
    args = parser().parse_args(argv)
    try:
        planner = Gen3Planner(min_distance=args.min_distance, solvers=[s.strip() for s in args.solvers.split(",") if s.strip()], table_z=args.table_z)
        service = PlannerService(handler(planner), 7)
    except KoopbridgeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.stdin_lifeline:
        threading.Thread(target=_lifeline, args=(service,), daemon=True).start()
    print(f"koopbridge drake planner: Kinova Gen3 as planner '{args.id}' in session '{args.session}' (solvers {[s for s, _ in planner.solvers]})", file=sys.stderr, flush=True)
    try:
        stats = service.serve(session=args.session, id=args.id, connect=args.connect, listen=args.listen, mode=args.mode, zenoh_config=args.zenoh_config)
    except KeyboardInterrupt:
        return 130
    except KoopbridgeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"koopbridge drake planner: stopped after {stats['plans']} plans, {stats['errors']} errors, {stats['busy']} busy replies", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
