"""The G1 survival scenario end to end (issue 30): collect expert data (``g1_data --held
locked``) → train (``koopbridge train --normalise --gamma 0.99``; EDMD and NNDM on raw units) →
track held-out references through the bridge (``g1_survival``, 0.10 rad, the replay floor
beside each model) → report; ``--aggregate R`` rounds of on-policy aggregation as in
``go2_scenario``. The default budget is CI's (about a minute: 300 windows, 200 iterations, 4
references of 40 steps); ``--full`` is the paper's (180k windows, 20k iterations, n_mult 16, 50
references of 200 steps, the six models).

    python -m koopbridge.experiments.g1_scenario --out OUT [--full] [--data DIR] [--models both,edmd] [--aggregate 1] [--held locked]

Writes ``OUT/scenario.json`` (every round's survival table with the models' test L_pred),
``OUT/data`` (unless ``--data``), ``OUT/round{r}/models/g1-{name}``, ``OUT/round{r}/track``
(``g1_survival``'s report, figures and MCAP), ``OUT/round{r}/aggregate`` and ``OUT/round{r}/data``
(r ≥ 1), as ``go2_scenario`` does. ``--held`` (default ``locked``, the 23-DoF G1) and
``--expert`` go to both the data and the tracking.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from . import legged_scenario as _legged

__all__ = ["SCENARIO", "main", "parser"]

#: The scenario this command line runs (``legged_scenario.G1_SCENARIO``).
SCENARIO = _legged.G1_SCENARIO


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m koopbridge.experiments.g1_scenario``."""
    return _legged.parser(SCENARIO, (__doc__ or "").split("\n\n")[0])


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the scenario; returns the exit code (2: bad arguments, 1: a step failed)."""
    return _legged.main(SCENARIO, argv, (__doc__ or "").split("\n\n")[0])


if __name__ == "__main__":
    sys.exit(main())
