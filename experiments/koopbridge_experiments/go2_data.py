"""The Go2's expert dataset through the Go2 simulator's in-process ``collect`` (the code a Zenoh
``collect`` request runs): the rl_sar expert under random velocity commands (SPEC's size: 180,000
windows of T = 15, data seed 42, split 140k/20k/20k), written as ``DIR/{train,val,test}.npz``
for ``koopbridge train --data DIR``.

    python -m koopbridge_experiments.go2_data --out DIR [--windows 180000] [--procs 2] [--noise 0.05] [--push 0.5]

Blocks, resumption and splits: ``legged_data``.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from .legged_data import DataRobot, parser, run

__all__ = ["ROBOT", "main"]

#: The Go2 as ``legged_data`` sees it.
ROBOT = DataRobot(
    name="go2_data",
    prog="python -m koopbridge_experiments.go2_data",
    simulator="koopbridge.adapters.legged.go2.sim:Go2Simulator",
    expert="the rl_sar expert under U([-0.5,-0.3,-0.8],[1,0.3,0.8]) velocity commands every 2 s",
)


def main(argv: Sequence[str] | None = None) -> int:
    """Collects (or resumes) the Go2's expert data; returns the exit code."""
    return run(ROBOT, parser(ROBOT, (__doc__ or "").split("\n\n")[0]), argv)


if __name__ == "__main__":
    sys.exit(main())
