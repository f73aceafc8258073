"""Command-line options shared by every Python adapter (and the Drake planner service): where to
serve (session, id, Zenoh endpoints) and how (lockstep or free-run). Mirrors the Rust
``koopbridge sim`` flags."""

from __future__ import annotations

import argparse
import os
import sys
import threading
from typing import Any

from ._native import Adapter


def add_zenoh_arguments(parser: argparse.ArgumentParser, *, id_default: str, id_help: str) -> argparse._ArgumentGroup:
    """Adds the group "serving" with ``--session --id --connect --listen --mode --zenoh-config``
    to ``parser`` (``--id`` with ``id_default`` and ``id_help``); returns the group."""
    g = parser.add_argument_group("serving (koopbridge protocol over Zenoh)")
    g.add_argument("--session", default="default", help="koopbridge session id: the root koopbridge/{session}/ (default: %(default)s)")
    g.add_argument("--id", default=id_default, help=f"{id_help} (default: %(default)s)")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="Zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--listen", action="append", default=[], metavar="ENDPOINT", help="Zenoh endpoint to listen on (repeatable; default tcp/127.0.0.1:0 for a peer)")
    g.add_argument("--mode", choices=["peer", "client", "router"], default="peer", help="Zenoh mode (default: %(default)s)")
    g.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 configuration file")
    return g


def add_lifeline_argument(group: argparse._ArgumentGroup) -> None:
    """Adds ``--stdin-lifeline`` (see ``start_lifeline``) to ``group``."""
    group.add_argument("--stdin-lifeline", action="store_true", help="stop serving when standard input closes (used by `koopbridge run`)")


def add_serve_arguments(parser: argparse.ArgumentParser) -> None:
    """Adds ``--session --id --connect --listen --mode --zenoh-config --free-run --rate --steps --wait-subscriber
    --seed --stdin-lifeline`` to ``parser``."""
    g = add_zenoh_arguments(parser, id_default="sim0", id_help="simulator id: keys koopbridge/{session}/sim/{id}/...")
    g.add_argument("--free-run", action="store_true", help="free-run mode: step at a fixed rate, publish states, apply the latest command")
    g.add_argument("--rate", type=float, metavar="HZ", help="free-run steps per second (default: real time, 1/dt)")
    g.add_argument("--steps", type=int, metavar="N", help="free-run: stop after N steps (default: run until stopped)")
    g.add_argument("--seed", type=int, help="free-run: seed of the initial state")
    g.add_argument("--wait-subscriber", type=float, metavar="SECONDS", help="free-run: wait up to SECONDS for a subscriber of the state stream before the first step (default: start at once)")
    add_lifeline_argument(g)


def zenoh_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments of ``serve`` that the options of ``add_zenoh_arguments`` give."""
    return dict(
        session=args.session,
        id=args.id,
        connect=args.connect,
        listen=args.listen,
        mode=args.mode,
        zenoh_config=args.zenoh_config,
    )


def start_lifeline(service: Any, args: argparse.Namespace) -> None:
    """With ``--stdin-lifeline``: a daemon thread that calls ``service.stop()`` when standard
    input reaches end of file (the parent went away)."""
    if getattr(args, "stdin_lifeline", False):
        threading.Thread(target=_lifeline, args=(service,), daemon=True).start()


def serve_from_args(adapter: Adapter, args: argparse.Namespace) -> dict[str, Any]:
    """Serves ``adapter`` as the parsed options say; returns its counters."""
    kw = zenoh_kwargs(args)
    if args.free_run:
        kw.update(free_run=True, rate_hz=args.rate, steps=args.steps, seed=args.seed, wait_subscriber=args.wait_subscriber)
    elif args.rate is not None or args.steps is not None or args.wait_subscriber is not None:
        raise SystemExit("error: --rate, --steps and --wait-subscriber need --free-run")
    start_lifeline(adapter, args)
    return adapter.serve(**kw)


def _lifeline(service: Any) -> None:
    """Stops ``service`` when standard input reaches end of file (the parent went away)."""
    # os.read on the descriptor, not sys.stdin.buffer: a thread blocked in the buffered reader holds
    # its lock, and interpreter shutdown (after SIGTERM stopped the service) then aborts on it.
    try:
        while os.read(sys.stdin.fileno(), 4096):
            pass
    except (OSError, ValueError):
        pass
    service.stop()
