"""The MuJoCo adapter: the Franka Panda (robosuite's model, joint-velocity servos) served as a
koopbridge simulator.

    python -m koopbridge.adapters.mujoco --session S --id arm0 [--state q,qd] [--model FILE]

``--describe`` prints what ``info`` reports (names, units, bounds, dt, MuJoCo version, the
actuation) as JSON and exits.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ...serving import run_main
from .model import ModelError, PandaOptions
from .sim import STATES, FrankaSimulator, SimFailure

__all__ = ["FrankaSimulator", "ModelError", "SimFailure", "main", "parser", "simulator"]


def parser() -> argparse.ArgumentParser:
    """The MuJoCo adapter's own options (``run_main`` adds ``--describe`` and the serving ones)."""
    d = PandaOptions()
    p = argparse.ArgumentParser(
        prog="python -m koopbridge.adapters.mujoco",
        description="Serve a Franka Panda in MuJoCo as a koopbridge simulator over Zenoh: joint-velocity "
        "commands, state [ee position, q, qd] (lockstep: info/reset/step queries; or --free-run).",
        epilog="Example: python -m koopbridge.adapters.mujoco --session demo --id arm0 --listen tcp/127.0.0.1:7501",
    )
    p.add_argument("--model", metavar="FILE", help="an MJCF file of a 7-joint arm with joints joint1..joint7 (default: robosuite's Panda)")
    p.add_argument("--state", choices=STATES, default="ee,q,qd", help="state layout: 17-D [ee(3), q(7), qd(7)] or 14-D [q, qd] (default: %(default)s)")
    p.add_argument("--kv", type=float, default=d.kv, help="velocity-servo gain in N·m·s/rad (default: %(default)s)")
    p.add_argument("--u-limit", type=float, default=d.u_limit, help="commands are clipped to ±this, rad/s (default: %(default)s)")
    p.add_argument("--no-gravcomp", action="store_true", help="turn gravity compensation off")
    p.add_argument("--ee-body", default=d.ee_body, help="body whose origin is the end effector (default: %(default)s)")
    p.add_argument("--reset-range", type=float, default=0.2, help="seeded reset: home + U(±this) rad, clipped to the limits (default: %(default)s)")
    p.add_argument("--env", default="franka-panda", help="environment name reported in info (default: %(default)s)")
    return p


def _warning(message: str) -> None:
    print(f"MuJoCo warning: {message.strip()}", file=sys.stderr, flush=True)


def simulator(args: argparse.Namespace) -> FrankaSimulator:
    """The ``FrankaSimulator`` the parsed command line describes. In this (adapter) process
    MuJoCo's warnings go to standard error instead of ``./MUJOCO_LOG.TXT``."""
    import mujoco

    mujoco.set_mju_user_warning(_warning)
    opts = PandaOptions(kv=args.kv, u_limit=args.u_limit, gravcomp=not args.no_gravcomp, ee_body=args.ee_body)
    return FrankaSimulator(args.model, state=args.state, options=opts, reset_range=args.reset_range, env=args.env)


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the MuJoCo adapter (``koopbridge.serving.run_main``); returns the exit code."""
    return run_main(simulator, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
