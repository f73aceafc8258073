"""The RL expert's own row of a legged scenario's tracking tasks (how hard each task is, issue 44
§3): for every tracking task of ``OUT/report.json`` that has a survival metric (the aggregation
task aside) and each of its references, the expert walks the reference's episode again — the
same start, warm-up and velocity commands (``legged.collect.expert_rollouts``) — from the
reference's first state with the reset request the scenario engine sent that task's rows (its
perturbation: the push drawn for that reference, the heavier body, the lower friction), scored
by the engine's own survival metric (``koopbridge.survival``). Adds ``expert`` to
``report.json`` and writes ``OUT/tracking/expert.md`` (the expert beside replay and every model
row):

    python -m koopbridge_experiments.legged_expert_row --robot go2 --out results/go2-survival

As a scenario's ``after-control`` hook it runs with the run's references; by hand, on any run
folder whose tracking tasks used references of ``legged_references`` (same ``--seed``, same
robot options). Before scoring, each reference is checked to be the expert's own rollout bit for
bit (else exit 2: the file is not these rollouts).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from koopbridge import InvalidInput, survival
from koopbridge.adapters.legged.collect import expert_rollouts

from .dataset_npz import write_atomic
from .legged_robots import REFERENCE_SEED, ROBOTS, stats
from .run_report import update_report


class Refused(Exception):
    """Input that cannot be scored (exit code 2)."""


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.legged_expert_row", description=(__doc__ or "").split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robot", choices=sorted(ROBOTS), required=True, help="the legged robot")
    p.add_argument("--out", required=True, help="the run's folder (holds report.json; tracking/expert.md is written there)")
    p.add_argument("--seed", type=int, default=REFERENCE_SEED, help="the references' seed, as given to legged_references (default: %(default)s)")
    p.add_argument("--held", choices=("servo", "locked"), default="locked", help="G1 only: the adapter's --held (default: %(default)s)")
    p.add_argument("--expert", choices=("fastsac", "ppo"), default="fastsac", help="G1 only: the walking policy (default: %(default)s)")
    return p


def scored_tasks(report: dict[str, Any]) -> list[dict[str, Any]]:
    """The tracking tasks the expert row is run for: a survival metric, not aggregation, and one
    references file for all (``Refused`` otherwise)."""
    tasks = [t for t in report.get("tracking") or [] if t.get("survival") and not t.get("aggregate")]
    if not tasks:
        raise Refused("report.json has no tracking task with a survival metric")
    files = {t["references_file"] for t in tasks}
    if len(files) > 1:
        raise Refused(f"the tracking tasks use several references files {sorted(files)}; the expert row needs one")
    return tasks


def task_name(t: dict[str, Any]) -> str:
    """A task's name in the table: its label, or ``nominal``."""
    return str(t.get("label") or "nominal")


def run(a: argparse.Namespace, report: dict[str, Any]) -> dict[str, Any]:
    """Runs the expert on every scored task of ``report``; returns its ``expert`` entry."""
    tasks = scored_tasks(report)
    with np.load(tasks[0]["references_file"]) as z:
        refs = np.asarray(z["x"], float)
    robot = ROBOTS[a.robot]
    sim = robot.simulator(a, 0)  # no state memory: a reset to a reference's start is cold, as the adapter's
    policy = robot.policy(sim)
    n = len(refs)
    for t in tasks:
        if len(t.get("perturbations") or [None] * n) != n:
            raise Refused(f"task {task_name(t)}: {len(t['perturbations'])} perturbations for {n} references")
    survivals: list[list[int]] = [[] for _ in tasks]
    falls = [0] * len(tasks)
    steps = max(int(t["steps"]) for t in tasks)
    window, began = 0, time.monotonic()
    for i in range(n):
        # One run per distinct perturbation of this reference (the nominal tasks share one).
        per_task = [json.dumps((t.get("perturbations") or [None] * n)[i] or {}, sort_keys=True) for t in tasks]
        distinct = sorted(set(per_task))
        while True:  # the windows legged_references kept: those whose start the simulator accepts
            if window > 2 * n + 20:
                raise Refused(f"no expert rollout of seed {a.seed} from window {window} on matches reference {i}")
            try:
                collected, distinct_runs = expert_rollouts(sim, policy, a.seed, window, steps, [json.loads(p) for p in distinct])
                break
            except InvalidInput:
                window += 1
        window += 1
        runs = [distinct_runs[distinct.index(p)] for p in per_task]
        if not np.array_equal(collected, refs[i, : steps + 1]):
            raise Refused(f"reference {i} is not the expert's rollout {window - 1} of seed {a.seed} "
                          f"(the references were made with another seed or robot options)")
        for j, (t, (x, fell)) in enumerate(zip(tasks, runs, strict=True)):
            spec = t["survival"]
            survivals[j].append(survival(x, refs[i], list(map(bool, fell)), float(spec["threshold"]), list(spec["states"]), int(t["steps"])))
            falls[j] += bool(fell.any())
        print(f"legged_expert_row: reference {i + 1}/{n} ({time.monotonic() - began:.0f} s)", file=sys.stderr, flush=True)
    return dict(
        robot=a.robot, seed=a.seed, references_file=tasks[0]["references_file"],
        what="the RL expert walking each reference's episode again (same start, warm-up and commands) "
             "from the reference's first state under the task's perturbation; the engine's survival metric",
        tasks=[dict(task=task_name(t), perturbation=t.get("perturbation"), survivals=s, runs_that_fell=f,
                    survival=stats(s, int(t["steps"]))) for t, s, f in zip(tasks, survivals, falls, strict=True)],
    )


def table(report: dict[str, Any], expert: dict[str, Any]) -> str:
    """``tracking/expert.md``: per task, replay, the expert and every model row (mean survival)."""
    tasks = scored_tasks(report)
    rows = sorted({r["row"].split("+")[0] for t in tasks for r in t["rows"] if r["row"] != "replay"})
    head = "| task | replay | RL expert (runs that fell) | " + " | ".join(rows) + " |"
    lines = [f"Mean survival of {len(expert['tasks'][0]['survivals'])} references (cap {tasks[0]['steps']}); "
             "the RL expert re-walks each reference's episode from its first state under the task's perturbation "
             f"(in brackets: its runs that fell within the {tasks[0]['steps']} steps, of {len(expert['tasks'][0]['survivals'])}).", "",
             head, "|" + "---|" * (3 + len(rows))]
    for t, e in zip(tasks, expert["tasks"], strict=True):
        by = {r["row"].split("+")[0]: r["survival"]["mean"] for r in t["rows"]}
        lines.append(f"| {e['task']} | {by.get('replay', float('nan')):.1f} | {e['survival']['mean']:.1f} ({e['runs_that_fell']}) | "
                     + " | ".join(f"{by[m]:.1f}" if m in by else "-" for m in rows) + " |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Runs, writes; returns the exit code (2: bad input)."""
    a = parser().parse_args(argv)
    try:
        report = json.loads((Path(a.out) / "report.json").read_text())
        expert = run(a, report)
        md = table(report, expert)
    except (Refused, OSError, KeyError, ValueError) as e:
        print(f"legged_expert_row: {e}", file=sys.stderr)
        return 2
    path = Path(a.out) / "tracking" / "expert.md"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(str(path), lambda f: f.write(md.encode()))  # type: ignore[attr-defined]
    update_report(Path(a.out) / "report.json", "expert", expert)
    print(md, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
