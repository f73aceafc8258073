"""Alias of ``python -m koopbridge.adapters.drake.planner`` (the Drake Gen3 planner service's command line), kept so that ``python -m koopbridge.adapters.drake_planner`` goes on working."""

import sys

from .drake.planner import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
