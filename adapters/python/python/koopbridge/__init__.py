"""koopbridge from Python.

- ``Simulator``, ``SimInfo``: the contract of a Python simulator (``koopbridge.simulator``);
  ``SimulatorAdapter`` serves any of them over Zenoh (lockstep or free-run) through the one
  Rust implementation of the protocol, ``run_main`` is the body of an adapter's command line
  (``koopbridge.serving``); ``koopbridge.testing.check_adapter`` checks a simulator the way
  the bridge will use it;
- ``Adapter``: the native base class under ``SimulatorAdapter``;
- ``KoopmanModel``: a trained neural Koopman model (``encode``, ``predict``, ``A``, ``B``, ``P``);
- ``BilinearModel``: a trained bilinear Koopman model (``predict``, ``A``, ``B``, ``N``);
- ``Mpc``: in-process receding-horizon MPC solves on a model;
- ``Client``: the querying side (simulators, MPC solves and configuration, training jobs, the
  model store, raw queries), all through the Rust ``bridge`` crate;
- ``ReferenceSystem``: the built-in Rust reference dynamics;
- ``koopbridge.adapters``: the simulator adapters, one subpackage per family (``fmu``,
  ``mujoco``, ``legged.go2``, ``legged.g1``, ``drake``, ``gym``; ``python -m
  koopbridge.adapters.fmu --help``). The paper's experiments are not in the wheel: they are
  the repository's ``experiments/`` (``koopbridge_experiments``, in the development venv).

Errors: every one is a ``KoopbridgeError``; ``BridgeTimeout`` is also a built-in
``TimeoutError``, ``RemoteError`` carries the reply's ``code``.
"""

from ._native import (
    PROTOCOL_VERSION,
    Adapter,
    BilinearModel,
    BridgeTimeout,
    Client,
    GoneError,
    InvalidInput,
    KoopbridgeError,
    KoopmanModel,
    Mpc,
    ReferenceSystem,
    RemoteError,
    Unsupported,
    __version__,
    survival,
)
from .serving import SimulatorAdapter, run_main
from .simulator import SimInfo, Simulator

__all__ = [
    "PROTOCOL_VERSION",
    "Adapter",
    "BilinearModel",
    "BridgeTimeout",
    "Client",
    "GoneError",
    "InvalidInput",
    "KoopbridgeError",
    "KoopmanModel",
    "Mpc",
    "ReferenceSystem",
    "RemoteError",
    "SimInfo",
    "Simulator",
    "SimulatorAdapter",
    "Unsupported",
    "__version__",
    "run_main",
    "survival",
]
