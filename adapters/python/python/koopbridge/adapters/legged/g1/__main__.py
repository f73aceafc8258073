"""The G1 adapter: the Unitree G1 humanoid in MuJoCo (mjlab's model, holosoma's walking expert)
served as a koopbridge simulator.

    python -m koopbridge.adapters.g1 --session S --id g1 [--model FILE] [--policy FILE | --expert ppo]

Inputs: 23 joint position targets (rad), held over 0.02 s (waist roll/pitch and wrist
pitch/yaw held at the default pose); state: the 53-D trimmed state (``--describe`` prints names,
units, bounds, the actuation and which components the state holds, as JSON). ``collect``
requests run the expert (``{"kind": "expert"}`` or ``{"kind": "expert+noise", "noise": 0.05}``)
or uniform targets in the adapter's own process.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ....serving import run_main
from .model import HOLDS, MODEL_PACKAGE, MODEL_VERSION, POLICIES, POLICY_PACKAGE, POLICY_VERSION, ModelError
from .sim import G1Simulator, SimFailure

__all__ = ["G1Simulator", "ModelError", "SimFailure", "main", "parser", "simulator"]


def parser() -> argparse.ArgumentParser:
    """The G1 adapter's own options (``run_main`` adds ``--describe`` and the serving ones)."""
    p = argparse.ArgumentParser(
        prog="python -m koopbridge.adapters.g1",
        description="Serve a Unitree G1 humanoid (29 DoF) in MuJoCo as a koopbridge simulator over Zenoh: 23 joint position "
        "targets (position servos at the policy's gains; waist roll/pitch and wrist pitch/yaw held at the default pose), the "
        "53-D state [base quaternion, body-frame linear and angular velocity, q and qd of 21 joints, pelvis height]; collect "
        "policies 'expert' and 'expert+noise' run holosoma's walking policy under random velocity commands.",
        epilog="Example: python -m koopbridge.adapters.g1 --session demo --id g1 --listen tcp/127.0.0.1:7512",
    )
    p.add_argument("--model", metavar="FILE", help=f"a g1.xml (default: the one in {MODEL_PACKAGE}=={MODEL_VERSION})")
    p.add_argument("--policy", metavar="FILE", help="the expert's ONNX policy, 100 observations -> 29 actions, kp/kd/dof_names in its "
                   f"metadata (default: --expert's file in {POLICY_PACKAGE}=={POLICY_VERSION})")
    p.add_argument("--expert", choices=sorted(POLICIES), default="fastsac", help="which shipped walking policy (default: %(default)s)")
    p.add_argument("--held", choices=HOLDS, default="servo", help="how the 6 non-input joints are held at the default pose: by their "
                   "servos (they give under load) or locked rigid, as on the 23-DoF G1 (default: %(default)s)")
    p.add_argument("--target-margin", type=float, default=0.0, metavar="RAD", help="input bounds = the joint ranges widened by RAD; "
                   "targets outside are clipped (default: %(default)s, the joint limits)")
    p.add_argument("--reset-range", type=float, default=0.05, help="seeded reset: default pose + U(+-this) rad per input joint, "
                   "heading U(+-pi) (default: %(default)s)")
    p.add_argument("--env", help="environment name reported in info (default: unitree-g1, with --held locked unitree-g1-locked)")
    p.add_argument("--quiet", action="store_true", help="do not print a line at every fall")
    return p


def _warning(message: str) -> None:
    print(f"MuJoCo warning: {message.strip()}", file=sys.stderr, flush=True)


def _fall(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def simulator(args: argparse.Namespace) -> G1Simulator:
    """The ``G1Simulator`` the parsed command line describes. In this (adapter) process MuJoCo's
    warnings go to standard error instead of ``./MUJOCO_LOG.TXT``."""
    import mujoco

    mujoco.set_mju_user_warning(_warning)
    return G1Simulator(
        args.model,
        args.policy,
        policy_name=args.expert,
        held=args.held,
        target_margin=args.target_margin,
        reset_range=args.reset_range,
        env=args.env,
        on_fall=None if args.quiet else _fall,
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the G1 adapter (``koopbridge.serving.run_main``); returns the exit code."""
    return run_main(simulator, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
