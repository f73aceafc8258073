"""The G1 tracking task and its survival steps through the bridge (SPEC "Legged robots", issue 30):
held-out expert references (holosoma's walking policy under random velocity commands over its
trained ranges), each tracked from its first state by the MPC service (``koopbridge serve mpc``)
with the G1 adapter (``python -m koopbridge.adapters.g1 --held locked``: the 23-DoF G1, its six
non-input joints locked) in lockstep in a child process; beside each model the open-loop replay
floor (the expert's recorded targets replayed from the same start). Writes ``report.json`` (the
survival table), ``survival.png``, ``tracking.png`` (21 joints of one reference),
``tracking.mcap``, ``table.md`` and ``onpolicy/{model}.npz``, as ``go2_survival`` does.

    python -m koopbridge.experiments.g1_survival --model DIR [--model DIR2 ...] --references 50 --out OUT [--held locked]

Survival (``go2_track`` on the G1's layout): steps until the mean absolute error over the
state's 21 joint positions first exceeds ``--threshold`` (0.10 rad, the paper's G1 figure) or
the pelvis falls (``g1_model.FALL``), capped at the reference length (200 steps of 0.02 s).
With ``--held servo`` (the 29-DoF G1 whose waist roll/pitch give under load, outside the state)
the replay floor drops from 198.6 to 36.5 steps (``g1_replay``): use ``locked`` for the paper's
23-DoF G1, as ``g1_data --held locked`` for its data.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

from . import legged_survival as _legged
from .go2_track import Reference

__all__ = ["ROBOT", "main", "parser", "run"]

#: The robot this command line runs (``legged_survival.G1``).
ROBOT = _legged.G1


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m koopbridge.experiments.g1_survival``."""
    return _legged.parser(ROBOT, (__doc__ or "").split("\n\n")[0])


def run(a: argparse.Namespace, refs: list[Reference] | None = None) -> dict[str, Any]:
    """Runs the task the parsed command line describes; returns the report (also written)."""
    return _legged.run(ROBOT, a, refs)


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the task; returns the exit code (2: bad arguments, a missing or wrong model)."""
    return _legged.main(ROBOT, argv, (__doc__ or "").split("\n\n")[0])


if __name__ == "__main__":
    sys.exit(main())
