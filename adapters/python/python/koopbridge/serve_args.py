"""Command-line options shared by every Python adapter: where to serve (session, id, Zenoh
endpoints) and how (lockstep or free-run). Mirrors the Rust ``koopbridge sim`` flags."""

from __future__ import annotations

import argparse
import sys
import threading
from typing import Any

from ._native import Adapter


def add_serve_arguments(parser: argparse.ArgumentParser) -> None:
    """Adds ``--session --id --connect --listen --mode --zenoh-config --free-run --rate --steps
    --seed --stdin-lifeline`` to ``parser``."""
    g = parser.add_argument_group("serving (koopbridge protocol over Zenoh)")
    g.add_argument("--session", default="default", help="koopbridge session id: the root koopbridge/{session}/ (default: %(default)s)")
    g.add_argument("--id", default="sim0", help="simulator id: keys koopbridge/{session}/sim/{id}/... (default: %(default)s)")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="Zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--listen", action="append", default=[], metavar="ENDPOINT", help="Zenoh endpoint to listen on (repeatable; default tcp/127.0.0.1:0 for a peer)")
    g.add_argument("--mode", choices=["peer", "client", "router"], default="peer", help="Zenoh mode (default: %(default)s)")
    g.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 configuration file")
    g.add_argument("--free-run", action="store_true", help="free-run mode: step at a fixed rate, publish states, apply the latest command")
    g.add_argument("--rate", type=float, metavar="HZ", help="free-run steps per second (default: real time, 1/dt)")
    g.add_argument("--steps", type=int, metavar="N", help="free-run: stop after N steps (default: run until stopped)")
    g.add_argument("--seed", type=int, help="free-run: seed of the initial state")
    g.add_argument("--stdin-lifeline", action="store_true", help="stop serving when standard input closes (used by `koopbridge run`)")


def serve_from_args(adapter: Adapter, args: argparse.Namespace) -> dict[str, Any]:
    """Serves ``adapter`` as the parsed options say; returns its counters."""
    kw: dict[str, Any] = dict(
        session=args.session,
        id=args.id,
        connect=args.connect,
        listen=args.listen,
        mode=args.mode,
        zenoh_config=args.zenoh_config,
    )
    if args.free_run:
        kw.update(free_run=True, rate_hz=args.rate, steps=args.steps, seed=args.seed)
    elif args.rate is not None or args.steps is not None:
        raise SystemExit("error: --rate and --steps need --free-run")
    if getattr(args, "stdin_lifeline", False):
        threading.Thread(target=_lifeline, args=(adapter,), daemon=True).start()
    return adapter.serve(**kw)


def _lifeline(adapter: Adapter) -> None:
    """Stops ``adapter`` when standard input reaches end of file (the parent went away)."""
    try:
        while sys.stdin.buffer.read(4096):
            pass
    except (OSError, ValueError):
        pass
    adapter.stop()
