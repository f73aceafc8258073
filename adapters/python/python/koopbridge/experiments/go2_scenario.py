"""The Go2 survival scenario end to end (issue 25 §3): collect expert data (``go2_data``) → train
(``koopbridge train --normalise --gamma 0.99``; EDMD and NNDM on raw units) → track held-out
references through the bridge (``go2_survival``) → report; with ``--aggregate R``, R rounds of
on-policy aggregation (the first model's closed loops on references of their own, never the
held-out ones, join the training data, ``go2_union``; every model is retrained on the union and
tracks the held-out references again). The default budget is CI's (about a
minute); ``--full`` is the paper's (SPEC: 180k windows, 20k iterations, n_mult 16, 50
references, the six models).

    python -m koopbridge.experiments.go2_scenario --out OUT [--full] [--data DIR] [--models both,edmd] [--aggregate 1]

Writes ``OUT/scenario.json`` (every round's survival table with the models' test L_pred),
``OUT/data`` (unless ``--data``), ``OUT/round{r}/models/{name}``, ``OUT/round{r}/track``
(``go2_survival``'s report, figures and MCAP), ``OUT/round{r}/aggregate`` (the closed loops aggregated after
round r) and ``OUT/round{r}/data`` (the union, r ≥ 1).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from . import legged_scenario as _legged
from .legged_scenario import AGGREGATION_SEED, BUDGETS, VARIANTS, train_command

__all__ = ["AGGREGATION_SEED", "BUDGETS", "VARIANTS", "main", "parser", "train_command"]

#: The scenario this command line runs (``legged_scenario.GO2_SCENARIO``).
SCENARIO = _legged.GO2_SCENARIO


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m koopbridge.experiments.go2_scenario``."""
    return _legged.parser(SCENARIO, (__doc__ or "").split("\n\n")[0])


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the scenario; returns the exit code (2: bad arguments, 1: a step failed)."""
    return _legged.main(SCENARIO, argv, (__doc__ or "").split("\n\n")[0])


if __name__ == "__main__":
    sys.exit(main())
