"""The contract of a Python simulator for koopbridge: the ``SimInfo`` it reports, the
``Simulator`` protocol it implements, and the input checks every simulator shares."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from ._native import InvalidInput

__all__ = ["SimInfo", "Simulator", "Closable", "as_input", "as_state"]

# The keys of `SimInfo` that the Rust side (`bridge::adapter::SimInfo`) reads as fields; every
# other key of `to_dict()` comes from `extra` and travels in the info reply's `extra` object.
_FIELDS = ("env", "dt", "state_names", "input_names", "u_min", "u_max", "kind", "version", "angle_indices")


@dataclass
class SimInfo(Mapping[str, Any]):
    """What a simulator is, as the ``info`` reply reports it (``bridge::adapter::SimInfo``).

    ``env``: environment name; ``dt``: seconds per ``step``; ``state_names``/``input_names``:
    one name per component of x and u; ``u_min``/``u_max``: input bounds (``±inf`` for none);
    ``kind``: simulator family (``fmu``, ``mujoco``, ...); ``version``: the simulator's version;
    ``angle_indices``: state components that are angles; ``extra``: anything else, JSON values
    only (units, model file, engine version), reaching clients as the reply's ``extra`` object.

    It also reads like the dict ``to_dict()`` returns (``info["dt"]``, ``info["fmu"]``), so code
    written against the older dict-returning ``info()`` keeps working.
    """

    env: str
    dt: float
    state_names: list[str]
    input_names: list[str]
    u_min: list[float]
    u_max: list[float]
    kind: str = "python"
    version: str = ""
    angle_indices: list[int] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.dt = float(self.dt)
        self.state_names = [str(n) for n in self.state_names]
        self.input_names = [str(n) for n in self.input_names]
        self.u_min = [float(v) for v in self.u_min]
        self.u_max = [float(v) for v in self.u_max]
        self.angle_indices = [int(i) for i in self.angle_indices]
        self.extra = dict(self.extra)
        self.validate()

    @property
    def nx(self) -> int:
        """State dimension."""
        return len(self.state_names)

    @property
    def nu(self) -> int:
        """Input dimension."""
        return len(self.input_names)

    def validate(self) -> None:
        """Raises ``ValueError`` naming the first inconsistency (what the Rust side would refuse)."""
        if not self.env:
            raise ValueError("SimInfo: env must not be empty")
        if not (self.dt > 0 and math.isfinite(self.dt)):
            raise ValueError(f"SimInfo: dt must be positive, got {self.dt}")
        if self.nx == 0:
            raise ValueError("SimInfo: the state has no components (state_names is empty)")
        if len(self.u_min) != self.nu or len(self.u_max) != self.nu:
            raise ValueError(f"SimInfo: {self.nu} input names but {len(self.u_min)} u_min and {len(self.u_max)} u_max values")
        for i, (lo, hi) in enumerate(zip(self.u_min, self.u_max, strict=False)):
            if math.isnan(lo) or math.isnan(hi) or lo > hi:
                raise ValueError(f"SimInfo: input {self.input_names[i]!r} has bounds [{lo}, {hi}]")
        for i in self.angle_indices:
            if not 0 <= i < self.nx:
                raise ValueError(f"SimInfo: angle index {i} is outside the {self.nx}-D state")
        for k, v in self.extra.items():
            if k in _FIELDS or k == "extra":
                raise ValueError(f"SimInfo: extra key {k!r} is a field name")
            try:
                json.dumps(v, allow_nan=False)
            except (TypeError, ValueError) as e:
                raise ValueError(f"SimInfo: extra[{k!r}] is not JSON-serialisable: {e}") from e

    def to_dict(self) -> dict[str, Any]:
        """The flat dict ``Adapter.info()`` returns to the Rust side: the fields, then ``extra``'s keys."""
        d: dict[str, Any] = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "extra"}
        d.update(self.extra)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SimInfo:
        """The inverse of ``to_dict``: known keys become fields, the others ``extra`` (an
        ``extra`` object, as in an ``info`` reply, is merged into it)."""
        if isinstance(d, SimInfo):
            return d
        known = {k: d[k] for k in _FIELDS if k in d and d[k] is not None}
        extra = {k: v for k, v in d.items() if k not in _FIELDS and k != "extra"}
        nested = d.get("extra")
        if isinstance(nested, Mapping):  # an `info` reply keeps them in an `extra` object
            extra.update(nested)
        return cls(**known, extra=extra)

    # Read-only mapping view of `to_dict()`.
    def __getitem__(self, key: str) -> Any:
        return self.to_dict()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.to_dict())

    def __len__(self) -> int:
        return len(self.to_dict())


@runtime_checkable
class Simulator(Protocol):
    """A discrete-time simulator ``x_{k+1} = f(x_k, u_k)`` that koopbridge can serve.

    Optional members, used when present: ``close()`` (free resources; called once when serving
    ends), ``collect(policy, seed, n_windows, T, start=0)`` (runs whole data windows
    in-process, see ``koopbridge.collect``) and ``step_status()`` (called after each served
    ``step``: ``None`` or a dict of the step's flags ``terminated`` (the task says the episode
    has ended: a fall, a Gymnasium termination), ``truncated`` (a time limit), ``clipped`` (the
    input was clipped to the bounds), each optional; they reach the client in the step reply
    and never stop serving). Errors: raise ``koopbridge.InvalidInput`` for a
    request that is wrong (``bad_request`` reply), ``koopbridge.Unsupported`` for one this
    simulator cannot honour, anything else for a failure (``sim_failure`` reply; the simulator
    must accept a fresh ``reset`` afterwards).
    """

    def info(self) -> SimInfo:
        """What the simulator is; called once before serving."""
        ...

    def reset(self, seed: int | None = None, x0: npt.ArrayLike | None = None) -> np.ndarray:
        """Starts a new episode and returns x_0: at ``x0`` if given, else an initial state
        drawn with ``seed`` (same seed, same state), else the simulator's default."""
        ...

    def step(self, u: np.ndarray) -> np.ndarray:
        """Applies ``u`` (``nu`` values) held over one ``dt``; returns the next state."""
        ...


@runtime_checkable
class Closable(Protocol):
    """A simulator that holds resources to free."""

    def close(self) -> None: ...


def as_input(u: npt.ArrayLike, nu: int, what: str = "u") -> np.ndarray:
    """``u`` as a float64 vector of ``nu`` finite values, else ``InvalidInput`` saying why."""
    try:
        a = np.asarray(u, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InvalidInput(f"{what} is not an array of numbers ({e})") from e
    if a.ndim > 1:
        raise InvalidInput(f"{what} must be 1-D, got shape {a.shape}")
    a = a.ravel()
    if a.size != nu:
        raise InvalidInput(f"{what} must have {nu} values, got {a.size}")
    if not np.all(np.isfinite(a)):
        raise InvalidInput(f"{what} must be finite, got {a.tolist()}")
    return a


def as_state(x: npt.ArrayLike, nx: int, what: str = "x0") -> np.ndarray:
    """A state given by a caller (e.g. ``x0``) as ``nx`` finite float64 values, else ``InvalidInput``."""
    return as_input(x, nx, what)

