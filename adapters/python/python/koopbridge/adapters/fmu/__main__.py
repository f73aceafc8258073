"""The FMU adapter: any FMI 2.0 or 3.0 co-simulation FMU served as a koopbridge simulator.

    python -m koopbridge.adapters.fmu MODEL.fmu --inputs u --outputs theta,omega --dt 0.02 \\
        --initial theta0,omega0 --x0-low=-6.28,-8 --x0-high=6.28,8 --session S --id fmu0

``--describe`` prints what ``info`` reports (the FMU's variables, units, types, start values,
FMI version) as strict JSON (null for no bound) and exits. Lists of numbers that start with a
minus sign need ``=`` (``--x0-low=-1,-2``).

Variables of every numeric FMI type can be inputs and outputs (Real/Float64/Float32, Integer,
Int8..UInt64, Boolean, Enumeration), each read and written with its own FMI function and float64
on the wire; a value that its type or the variable's min/max cannot hold is a bad request naming
the variable (see ``fmu.variables``). An FMI 3 array ``y`` stands for its elements ``y[0]``,
``y[1]``, ... (``M[0,1]`` for two dimensions; zero-based, row-major); one element may be named
alone as an output. ``--param n=5`` may set a structural parameter, and so an array's size.
Variables that cannot be served (String, Binary, Clock, a variable that cannot be set in the
role asked, an array of unknown size) are refused at start-up with the reason.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

from ...serving import SimulatorAdapter, run_main
from .sim import FmuError, FmuSimulator

__all__ = ["FmuAdapter", "FmuError", "FmuSimulator", "main", "parser", "simulator"]


class FmuAdapter(SimulatorAdapter):
    """A ``SimulatorAdapter`` serving an ``FmuSimulator`` built from the same arguments."""

    def __init__(self, path: str, inputs: Sequence[str], outputs: Sequence[str], **kwargs: Any) -> None:
        super().__init__(FmuSimulator(path, inputs, outputs, **kwargs))


def _names(s: str) -> list[str]:
    return [n.strip() for n in s.split(",") if n.strip()]


def _floats(s: str) -> list[float]:
    try:
        return [float(v) for v in s.split(",") if v.strip()]
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got '{s}'") from e


def _param(s: str) -> tuple[str, float]:
    name, sep, value = s.partition("=")
    try:
        if not sep:
            raise ValueError
        return name.strip(), float(value)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got '{s}'") from e


def parser() -> argparse.ArgumentParser:
    """The FMU adapter's own options (``run_main`` adds ``--describe`` and the serving ones)."""
    p = argparse.ArgumentParser(
        prog="python -m koopbridge.adapters.fmu",
        description="Serve an FMI 2.0/3.0 co-simulation FMU as a koopbridge simulator over Zenoh "
        "(lockstep: info/reset/step queries; or --free-run). Inputs and outputs may be of any numeric FMI type "
        "(float64 on the wire; a value the type or the variable's min/max cannot hold is a bad request naming it); "
        "FMI 3 arrays expand to their elements; String, Binary and Clock variables are refused at start-up.",
        epilog="Example: python -m koopbridge.adapters.fmu adapters/fmu/build/damped_pendulum.fmu "
        "--inputs u --outputs theta,omega --dt 0.02 --initial theta0,omega0 "
        "--x0-low=-6.283,-8 --x0-high=6.283,8 --session demo --id fmu0",
    )
    p.add_argument("fmu", help="the .fmu file")
    p.add_argument("--inputs", type=_names, default=[], metavar="NAMES", help="comma-separated input variables (u), in order: inputs or tunable parameters of any numeric type; an FMI 3 array name stands for all its elements")
    p.add_argument("--outputs", type=_names, required=True, metavar="NAMES", help="comma-separated output variables (the state x), in order; an FMI 3 array name stands for all its elements y[0], y[1], ..., or name one element y[1] / M[0,1] (zero-based)")
    p.add_argument("--dt", type=float, help="communication step in seconds (default: the FMU's default experiment step)")
    p.add_argument("--initial", type=_names, metavar="NAMES", help="variables set to x0 on reset, one per output (default: the outputs if settable)")
    p.add_argument("--x0-low", type=_floats, metavar="VALUES", help="lower corner of the initial-state draw of a seeded reset")
    p.add_argument("--x0-high", type=_floats, metavar="VALUES", help="upper corner of the initial-state draw of a seeded reset")
    p.add_argument("--u-min", type=_floats, metavar="VALUES", help="input lower bounds reported in info (default: the variables' min)")
    p.add_argument("--u-max", type=_floats, metavar="VALUES", help="input upper bounds reported in info (default: the variables' max)")
    p.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE", help="start value set on every reset, checked against the variable's type and min/max at start-up (repeatable); may set an FMI 3 structural parameter (array size)")
    p.add_argument("--env", help="environment name reported in info (default: the FMU's model name)")
    p.add_argument("--angles", type=lambda s: [int(v) for v in s.split(",") if v], default=[], metavar="INDICES", help="state indices that are angles")
    return p


def simulator(args: argparse.Namespace) -> FmuSimulator:
    """The ``FmuSimulator`` the parsed command line describes."""
    return FmuSimulator(
        args.fmu,
        args.inputs,
        args.outputs,
        dt=args.dt,
        initial=args.initial,
        x0_low=args.x0_low,
        x0_high=args.x0_high,
        u_min=args.u_min,
        u_max=args.u_max,
        parameters=dict(args.param),
        env=args.env,
        angle_indices=args.angles,
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the FMU adapter (``koopbridge.serving.run_main``); returns the exit code."""
    return run_main(simulator, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
