"""Alias of ``python -m koopbridge.adapters.drake.sim`` (the Drake Gen3 simulator's command line), kept so that ``python -m koopbridge.adapters.drake_sim`` goes on working."""

import sys

from .drake.sim import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
