"""The Go2 tracking task and its survival steps through the bridge (SPEC "Legged robots", issue
25 §3): held-out expert references, each tracked from its first state by the MPC service
(``koopbridge serve mpc``, which picks the controller by the model's kind: the constrained QP
for Koopman and EDMD models, random shooting with 1000 sequences for an NNDM) with the Go2
adapter in lockstep in a child process; beside each model the open-loop replay floor (the
expert's recorded targets replayed from the same start). Writes ``report.json`` (the survival
table), ``survival.png`` (histograms), ``tracking.png`` (joint tracking of one reference),
``tracking.mcap`` (that reference's run of the first model, for Foxglove), ``table.md`` and
``onpolicy/{model}.npz`` (the closed loops as training windows, for on-policy aggregation).

    python -m koopbridge.experiments.go2_survival --model DIR [--model DIR2 ...] --references 50 --out OUT

Survival (``go2_track``): steps until the mean absolute joint-position error first exceeds
``--threshold`` (0.16 rad) or the base falls, capped at the reference length. Every run starts
with ``reset(x0 = the reference's first state)`` on an adapter that never saw that state, so the
physics starts from the 35-D state alone (lagged motor torques zero, base at x = y = 0): the
replay floor is then the expert's own open-loop drift, which feedback must beat.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from . import legged_survival as _legged
from .go2_track import Reference
from .legged_survival import ModelEntry, SetupError, markdown_table, model_entries, q_weights, stats

__all__ = ["Bridge", "ModelEntry", "SetupError", "main", "markdown_table", "model_entries", "parser", "q_weights", "run", "stats"]

#: The robot this command line runs (``legged_survival.GO2``).
ROBOT = _legged.GO2
SIM_ID = ROBOT.sim_id
MPC_ID = ROBOT.mpc_id


class Bridge(_legged.Bridge):
    """The Go2 adapter (``python -m koopbridge.adapters.go2``) and the MPC service as child
    processes of one fresh session, and a ``Client`` of it (``legged_survival.Bridge``)."""

    def __init__(self, models: list[ModelEntry], log_dir: Path, session: str | None = None, adapter_args: Sequence[str] = ()):
        super().__init__(ROBOT, models, log_dir, session, adapter_args)


def run(a: argparse.Namespace, refs: list[Reference] | None = None) -> dict[str, Any]:
    """Runs the task the parsed command line describes; returns the report (also written)."""
    return _legged.run(ROBOT, a, refs)


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m koopbridge.experiments.go2_survival``."""
    return _legged.parser(ROBOT, (__doc__ or "").split("\n\n")[0])


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the task; returns the exit code (2: bad arguments, a missing or wrong model)."""
    return _legged.main(ROBOT, argv, (__doc__ or "").split("\n\n")[0])


if __name__ == "__main__":
    sys.exit(main())
