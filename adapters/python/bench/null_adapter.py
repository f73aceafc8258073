"""A Python adapter whose step does nothing (x⁺ = x): isolates the SDK's own round-trip cost.
Run: python adapters/python/bench/null_adapter.py --session S --id null --connect EP"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import koopbridge
from koopbridge.serve_args import add_serve_arguments, serve_from_args


class Null(koopbridge.Adapter):
    """nx = 2, nu = 1, dt = 0.02; the state never changes."""

    def __init__(self) -> None:
        self.x = np.zeros(2)

    def info(self):
        return dict(env="null", kind="python-null", dt=0.02, state_names=["a", "b"], input_names=["u"], u_min=[-8.0], u_max=[8.0])

    def reset(self, seed=None, x0=None):
        self.x = np.zeros(2) if x0 is None else np.asarray(x0, float)
        return self.x

    def step(self, u):
        return self.x


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__)
    add_serve_arguments(p)
    serve_from_args(Null(), p.parse_args())
    sys.exit(0)
