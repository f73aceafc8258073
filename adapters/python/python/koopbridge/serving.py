"""Serving any ``Simulator`` over Zenoh: ``SimulatorAdapter`` (the native ``Adapter`` around a
simulator, with the shared input checks) and ``run_main``, the body of every
``python -m koopbridge.adapters.X`` entry point."""

from __future__ import annotations

import argparse
import inspect
import json
import signal
import sys
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from ._native import Adapter, KoopbridgeError, Unsupported
from .collect import Collector, Policy, Windows, collect_windows, policy_from_json
from .serve_args import add_serve_arguments, serve_from_args
from .simulator import Closable, SimInfo, Simulator, as_input, as_state

__all__ = ["SimulatorAdapter", "run_main"]


class SimulatorAdapter(Adapter):
    """A koopbridge ``Adapter`` serving ``sim`` (any ``Simulator``).

    Before the simulator sees a request, ``u`` is checked to be ``nu`` finite values and ``x0``
    ``nx`` finite values (``InvalidInput`` otherwise: a ``bad_request`` reply); the states the
    simulator returns go out as float64 vectors (the Rust side refuses a wrong length or a
    non-finite value with a ``sim_failure`` reply). ``info()`` is read once, here.
    """

    def __init__(self, sim: Simulator) -> None:
        if not isinstance(sim, Simulator):
            raise TypeError(f"{type(sim).__name__} is not a koopbridge Simulator (it needs info, reset and step)")
        self.sim = sim
        self.sim_info = SimInfo.from_dict(sim.info())

    def info(self) -> dict[str, Any]:
        """The simulator's ``SimInfo`` as the flat dict the Rust side reads."""
        return self.sim_info.to_dict()

    def reset(self, seed: int | None = None, x0: npt.ArrayLike | None = None, perturbation: Mapping[str, Any] | None = None) -> np.ndarray:
        """Checks ``x0`` and resets the simulator; a ``perturbation`` (PROTOCOL.md "reset") goes
        to a simulator whose ``reset`` takes one, else it is ``Unsupported``."""
        if x0 is not None:
            x0 = as_state(x0, self.sim_info.nx, "x0")
        if perturbation is None:
            return np.asarray(self.sim.reset(seed=seed, x0=x0), dtype=np.float64)
        if "perturbation" not in inspect.signature(self.sim.reset).parameters:
            raise Unsupported(f"{type(self.sim).__name__}.reset() takes no perturbation (the legged adapters' does)")
        return np.asarray(self.sim.reset(seed=seed, x0=x0, perturbation=dict(perturbation)), dtype=np.float64)

    def step(self, u: npt.ArrayLike) -> np.ndarray:
        """Checks ``u`` and steps the simulator."""
        u = as_input(u, self.sim_info.nu, "u")
        return np.asarray(self.sim.step(u), dtype=np.float64)

    def step_status(self) -> dict[str, bool] | None:
        """The simulator's ``step_status()`` after a step (flags of the step reply, see
        ``Simulator``), or ``None`` when it has none."""
        own = getattr(self.sim, "step_status", None)
        return own() if callable(own) else None

    def collect(self, policy: Policy | Mapping[str, Any], seed: int, n_windows: int, T: int, start: int = 0) -> Windows:
        """Windows ``start .. start + n_windows - 1`` of the collection with ``seed`` (see
        ``koopbridge.collect``), run in this process by the simulator's own ``collect`` if it has
        one, else step by step; ``policy`` may be its JSON form. What a Zenoh ``collect``
        request will call."""
        p = policy_from_json(policy) if isinstance(policy, Mapping) else policy
        if isinstance(self.sim, Collector):
            return self.sim.collect(p, seed, n_windows, T, start=start)
        return collect_windows(self.sim, p, seed, n_windows, T, start=start)

    def close(self) -> None:
        """Closes the simulator if it has ``close()``."""
        if isinstance(self.sim, Closable):
            self.sim.close()


def _strict_json(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by None (null, "no bound", as ``info`` replies)."""
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {k: _strict_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_strict_json(v) for v in obj]
    return obj


def run_main(
    factory: Callable[[argparse.Namespace], Simulator],
    parser: argparse.ArgumentParser,
    argv: Sequence[str] | None = None,
) -> int:
    """Runs an adapter's command line; returns the exit code.

    ``parser`` holds the adapter's own options; ``run_main`` adds ``--describe`` and the serving
    options (``koopbridge.serve_args``), parses ``argv``, builds the simulator with
    ``factory(args)`` (a ``KoopbridgeError`` there is printed, exit code 2), then either prints
    its info as JSON (``--describe``) or serves it until stopped (Ctrl-C, SIGTERM, the
    ``--stdin-lifeline`` closing, or the free-run step limit) and prints the adapter's counters
    (after Ctrl-C too: ``Adapter.last_stats``).
    Exit codes: 0 done, 1 serving failed, 2 bad set-up, 130 interrupted.
    """
    parser.add_argument("--describe", action="store_true", help="print the info this adapter reports (JSON) and exit")
    add_serve_arguments(parser)
    args = parser.parse_args(argv)
    try:
        adapter = SimulatorAdapter(factory(args))
    except (KoopbridgeError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    info = adapter.sim_info
    tag = f"koopbridge {info.kind} adapter"
    try:
        if args.describe:
            json.dump(_strict_json(info.to_dict()), sys.stdout, indent=2, default=str, allow_nan=False)
            print()
            return 0
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, lambda *_: adapter.stop())
        print(f"{tag}: {info.env} as sim '{args.id}' in session '{args.session}'", file=sys.stderr, flush=True)
        stats = serve_from_args(adapter, args)
        print(f"{tag}: stopped after {stats.get('steps', 0)} steps; counters {json.dumps(stats)}", file=sys.stderr)
        return 0
    except KeyboardInterrupt:
        stats = adapter.last_stats or {}
        print(f"{tag}: interrupted after {stats.get('steps', 0)} steps; counters {json.dumps(stats)}", file=sys.stderr)
        return 130
    except KoopbridgeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    finally:
        adapter.close()
