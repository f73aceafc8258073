"""koopbridge from Python.

- ``Adapter``: base class of simulators written in Python, served over Zenoh (lockstep or
  free-run) by the one Rust implementation of the protocol;
- ``KoopmanModel``: a trained neural Koopman model (``encode``, ``predict``, ``A``, ``B``, ``P``);
- ``BilinearModel``: a trained bilinear Koopman model (``predict``, ``A``, ``B``, ``N``);
- ``Mpc``: in-process receding-horizon MPC solves on a model;
- ``Client``: the querying side (simulators, MPC service, raw queries of the other services);
- ``ReferenceSystem``: the built-in Rust reference dynamics;
- ``koopbridge.adapters.fmu``: the FMU adapter (``python -m koopbridge.adapters.fmu --help``).
"""

from ._native import (
    PROTOCOL_VERSION,
    Adapter,
    BilinearModel,
    GoneError,
    InvalidInput,
    KoopbridgeError,
    KoopmanModel,
    Mpc,
    ReferenceSystem,
    RemoteError,
    TimeoutError,
    Unsupported,
    __version__,
)
from .client import Client

__all__ = [
    "PROTOCOL_VERSION",
    "Adapter",
    "BilinearModel",
    "Client",
    "GoneError",
    "InvalidInput",
    "KoopbridgeError",
    "KoopmanModel",
    "Mpc",
    "ReferenceSystem",
    "RemoteError",
    "TimeoutError",
    "Unsupported",
    "__version__",
]
