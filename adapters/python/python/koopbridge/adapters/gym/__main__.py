"""The Gymnasium adapter: any Gymnasium environment with a Box action space served as a koopbridge
simulator.

    python -m koopbridge.adapters.gym ENV_ID [--state auto|qpos,qvel|obs] [--dt S] [--make-kwargs JSON] --session S --id ID

Inputs: the action's components (bounds from the Box, actions outside it clipped); dt: the
environment's; state: the full MuJoCo state ``[qpos, qvel]`` for MuJoCo-based environments
(``reset(x0)`` exact), else the observation. Episode termination and truncation are printed to
standard error and never stop the adapter. ``--describe`` prints the info as JSON and exits.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

from ...serving import run_main
from .sim import STATES, GymError, GymSimulator, SimFailure

__all__ = ["GymError", "GymSimulator", "SimFailure", "main", "parser", "simulator"]


def parser() -> argparse.ArgumentParser:
    """The Gymnasium adapter's own options (``run_main`` adds ``--describe`` and the serving ones)."""
    p = argparse.ArgumentParser(
        prog="python -m koopbridge.adapters.gym",
        description="Serve a Gymnasium environment with a Box action space as a koopbridge simulator over Zenoh: "
        "inputs = the action components, dt = env.dt, state = the full MuJoCo state [qpos, qvel] for MuJoCo-based "
        "environments (exact reset(x0)) or the observation. Episode ends are reported on stderr and in the step reply (terminated/truncated); stepping goes on.",
        epilog="Examples: python -m koopbridge.adapters.gym InvertedPendulum-v5 --session demo --id pend --listen tcp/127.0.0.1:7521\n"
        "          python -m koopbridge.adapters.gym Reacher-v5 --describe\n"
        "          python -m koopbridge.adapters.gym Pendulum-v1 --make-kwargs '{\"g\": 9.81}' --describe",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("env_id", metavar="ENV_ID", help="a registered Gymnasium id, e.g. InvertedPendulum-v5, Reacher-v5, Pendulum-v1")
    p.add_argument(
        "--state",
        choices=STATES,
        default="auto",
        help="state layout: qpos,qvel (MuJoCo environments: the full state) or obs "
        "(the observation; reset(x0) only when it is [qpos, qvel]); auto picks qpos,qvel when it can (default: %(default)s)",
    )
    p.add_argument("--dt", type=float, metavar="SECONDS", help="seconds per step, for an environment without env.unwrapped.dt (default: the environment's)")
    p.add_argument(
        "--make-kwargs",
        type=json.loads,
        default={},
        metavar="JSON",
        help='a JSON object passed to gymnasium.make, e.g. \'{"max_episode_steps": 200, "reset_noise_scale": 0.1}\'',
    )
    p.add_argument("--quiet", action="store_true", help="do not print a line at every episode end")
    return p


def _print(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def simulator(args: argparse.Namespace) -> GymSimulator:
    """The ``GymSimulator`` the parsed command line describes. In this (adapter) process MuJoCo's
    warnings go to standard error instead of ``./MUJOCO_LOG.TXT`` (when MuJoCo is installed)."""
    try:
        import mujoco

        mujoco.set_mju_user_warning(lambda m: _print(f"MuJoCo warning: {m.strip()}"))
    except ImportError:
        pass
    kwargs: Any = args.make_kwargs
    if not isinstance(kwargs, dict):
        raise GymError(f"--make-kwargs must be a JSON object, got {json.dumps(kwargs)}")
    return GymSimulator(args.env_id, state=args.state, dt=args.dt, make_kwargs=kwargs, on_episode_end=None if args.quiet else _print)


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the Gymnasium adapter (``koopbridge.serving.run_main``); returns the exit code."""
    return run_main(simulator, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
