"""The G1's expert dataset through the G1 simulator's in-process ``collect`` (the code a Zenoh
``collect`` request runs): holosoma's walking policy under random velocity commands over its
trained ranges (±1 m/s, ±1 m/s, ±1 rad/s, changed every 2 s; SPEC's size by default: 180,000
windows of T = 15, data seed 42, split 140k/20k/20k), written as ``DIR/{train,val,test}.npz``
for ``koopbridge train --data DIR``.

    python -m koopbridge_experiments.g1_data --out DIR [--windows 180000] [--procs 2] [--held locked] [--noise 0.05] [--push 0.5]

Blocks, resumption and splits: ``legged_data``.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from .legged_data import DataRobot, parser, run

__all__ = ["ROBOT", "main"]

#: The G1 as ``legged_data`` sees it.
ROBOT = DataRobot(
    name="g1_data",
    prog="python -m koopbridge_experiments.g1_data",
    simulator="koopbridge.adapters.legged.g1.sim:G1Simulator",
    expert="holosoma's G1 walking policy under U([-1,-1,-1],[1,1,1]) velocity commands every 2 s "
    "(waist roll/pitch and wrist pitch/yaw held at the default pose)",
)


def main(argv: Sequence[str] | None = None) -> int:
    """Collects (or resumes) the G1's expert data; returns the exit code."""
    p = parser(ROBOT, (__doc__ or "").split("\n\n")[0])
    p.add_argument("--held", choices=("servo", "locked"), default="servo", help="the adapter's --held: the 6 non-input joints held "
                   "by their servos or locked rigid (default: %(default)s)")
    p.add_argument("--expert", dest="policy_name", choices=("fastsac", "ppo"), default="fastsac", help="the walking policy (default: %(default)s)")
    return run(ROBOT, p, argv, options=("held", "policy_name"))


if __name__ == "__main__":
    sys.exit(main())
