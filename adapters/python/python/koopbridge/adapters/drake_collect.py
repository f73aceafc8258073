"""Alias of ``python -m koopbridge.adapters.drake.collect`` (the Kinova data collection's command line), kept so that ``python -m koopbridge.adapters.drake_collect`` goes on working."""

import sys

from .drake.collect import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
