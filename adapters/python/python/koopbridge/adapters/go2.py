"""Alias of ``python -m koopbridge.adapters.legged.go2`` (the Go2 adapter's command line), kept so that ``python -m koopbridge.adapters.go2`` goes on working."""

import sys

from .legged.go2.__main__ import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
