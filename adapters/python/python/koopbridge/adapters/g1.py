"""Alias of ``python -m koopbridge.adapters.legged.g1`` (the G1 adapter's command line), kept so that ``python -m koopbridge.adapters.g1`` goes on working."""

import sys

from .legged.g1.__main__ import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
