"""The Drake Gen3 planner as a koopbridge participant: ``…/planner/{id}/plan`` answered by the
two-pass trajectory optimisation of ``drake.plan``, served by the Rust ``PlannerService``.

    python -m koopbridge.adapters.drake_planner --session S --id planner0

Request JSON ``{"start": [7], "goal": [7], "dt": s}``; reply JSON ``{"t": [n], "q": [n][7],
"qd": [n][7], "duration", "dt", "passes": [{"name", "solver", "status", "solve_time_s",
"cost"}]}``. Errors: ``infeasible`` (naming the pass and the solvers' statuses), ``bad_request``
(bad JSON, NaN, out-of-limits configuration, bad dt), ``dimension``, ``busy`` (a plan is running).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

from ..._native import KoopbridgeError, PlannerService
from ...serve_args import add_lifeline_argument, add_zenoh_arguments, start_lifeline, zenoh_kwargs
from .plan import Gen3Planner

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
    p.add_argument("--ipopt-max-iterations", type=int, default=300, help="IPOPT's iteration limit per pass, the fallback after SNOPT (default: %(default)s)")
    g = add_zenoh_arguments(p, id_default="planner0", id_help="planner id: key koopbridge/{session}/planner/{id}/plan")
    add_lifeline_argument(g)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the planner service; returns the exit code."""
    args = parser().parse_args(argv)
    try:
        planner = Gen3Planner(min_distance=args.min_distance, solvers=[s.strip() for s in args.solvers.split(",") if s.strip()], table_z=args.table_z, ipopt_max_iterations=args.ipopt_max_iterations)
        service = PlannerService(handler(planner), 7)
    except KoopbridgeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    start_lifeline(service, args)
    print(f"koopbridge drake planner: Kinova Gen3 as planner '{args.id}' in session '{args.session}' (solvers {[s for s, _ in planner.solvers]})", file=sys.stderr, flush=True)
    try:
        stats = service.serve(**zenoh_kwargs(args))
    except KeyboardInterrupt:
        return 130
    except KoopbridgeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"koopbridge drake planner: stopped after {stats['plans']} plans, {stats['errors']} errors, {stats['busy']} busy replies", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
