"""Rows of tracking reports compared reference by reference (issue 44 §4: a regulariser's gain
over training seeds, paired by reference): for each task and each pair of rows — one pair per
training seed, the two rows from any runs that scored the same references — the mean survival
of each row, their paired difference (mean ± standard error; references better / worse), and over
all pairs the gain of B over A in percent of A's mean.

    python -m koopbridge_experiments.paired_rows \\
        --pair 'runs/base-s0/report.json#base0+{task}' 'runs/both-s0/report.json#both0+{task}' \\
        --pair 'runs/base-s1/report.json#base1+{task}' 'runs/both-s1/report.json#both1+{task}' \\
        --tasks nominal,push,mass --names base,+both [--json gains.json]

A row is ``REPORT#ROW``: the row named ROW (``{task}`` replaced by each task) in any tracking
task of that ``report.json``, an aggregation round's too (``koopbridge run --aggregate``: its
model's rows are ``MODEL-aggN…``). Prints a Markdown table; exit code 2 names a missing report or row,
or two rows of a pair scored on different numbers of references.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .legged_robots import stats


class Refused(Exception):
    """Rows that cannot be paired (exit code 2)."""


def survivals(spec: str, task: str, cache: dict[Path, dict[str, list[float]]]) -> list[float]:
    """The per-reference survivals of row ``spec`` (``REPORT#ROW``) for ``task``."""
    report, sep, row = spec.replace("{task}", task).partition("#")
    if not sep or not row:
        raise Refused(f"{spec!r}: a row is REPORT#ROW")
    path = Path(report)
    if path not in cache:
        try:
            r = json.loads(path.read_text())
        except (OSError, ValueError) as e:
            raise Refused(f"{path}: {e}") from e
        # The first pass's tasks, then every aggregation round's (their models are named `…-aggN`).
        tasks = list(r.get("tracking", [])) + [t for a in r.get("tracking_aggregation", []) for t in a["tracking"]]
        cache[path] = {w["row"]: w["survivals"] for t in tasks for w in t["rows"] if "survivals" in w}
    rows = cache[path]
    if row not in rows:
        raise Refused(f"{path} has no tracking row {row!r} (it has {', '.join(sorted(rows)) or 'none'})")
    return [float(v) for v in rows[row]]


def compare(pairs: Sequence[tuple[str, str]], tasks: Sequence[str]) -> list[dict[str, Any]]:
    """Per task: each pair's means and paired difference, and the gain over all pairs."""
    cache: dict[Path, dict[str, list[float]]] = {}
    out = []
    for task in tasks:
        per, diffs = [], []
        for a_spec, b_spec in pairs:
            a, b = survivals(a_spec, task, cache), survivals(b_spec, task, cache)
            if len(a) != len(b):
                raise Refused(f"{task}: {a_spec} has {len(a)} references, {b_spec} {len(b)}")
            d = [y - x for x, y in zip(a, b, strict=True)]
            diffs += d
            per.append(dict(a=stats(a)["mean"], b=stats(b)["mean"], diff=stats(d), better=sum(v > 0 for v in d),
                            worse=sum(v < 0 for v in d)))
        a_mean = sum(p["a"] for p in per) / len(per)
        b_mean = sum(p["b"] for p in per) / len(per)
        out.append(dict(task=task, pairs=per, a=a_mean, b=b_mean, gain_percent=100.0 * (b_mean - a_mean) / a_mean,
                        diff=stats(diffs)))
    return out


def table(result: Sequence[dict[str, Any]], names: tuple[str, str]) -> str:
    """The comparison as a Markdown table."""
    a, b = names
    lines = [f"| task | pairs | {a} | {b} | {b} − {a} (% of {a}) | paired, all pairs (mean ± sem) | per pair (mean ± sem; better / worse) |",
             "|---|---|---|---|---|---|---|"]
    for r in result:
        each = "; ".join(f"{p['a']:.1f} → {p['b']:.1f}: {p['diff']['mean']:+.1f} ± {p['diff']['sem']:.1f} ({p['better']} / {p['worse']})"
                         for p in r["pairs"])
        lines.append(f"| {r['task']} | {len(r['pairs'])} | {r['a']:.1f} | {r['b']:.1f} | {r['gain_percent']:+.1f} % | "
                     f"{r['diff']['mean']:+.1f} ± {r['diff']['sem']:.1f} | {each} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.paired_rows",
                                description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--pair", nargs=2, action="append", required=True, metavar=("A", "B"),
                   help="two rows REPORT#ROW scored on the same references (one pair per training seed)")
    p.add_argument("--tasks", default="", help="comma-separated task names for {task} (default: one, no substitution)")
    p.add_argument("--names", default="A,B", help="the two rows' names in the table (default A,B)")
    p.add_argument("--json", type=Path, help="also write the comparison here")
    args = p.parse_args(argv)
    tasks = [t for t in args.tasks.split(",") if t] or [""]
    names = tuple(args.names.split(",", 1)) if "," in args.names else ("A", "B")
    try:
        result = compare([tuple(x) for x in args.pair], tasks)
    except Refused as e:
        print(f"paired_rows: {e}", file=sys.stderr)
        return 2
    print(table(result, names))  # type: ignore[arg-type]
    if args.json:
        tmp = args.json.with_suffix(args.json.suffix + ".tmp")
        tmp.write_text(json.dumps(result, indent=1))
        tmp.replace(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
