"""Type stubs of the pyo3 extension module ``koopbridge._native``."""

from collections.abc import Callable, Sequence
from os import PathLike
from types import TracebackType
from typing import Any, Literal, Self, TypeAlias, final, overload

import numpy as np
import numpy.typing as npt
from typing_extensions import disjoint_base

__all__ = [
    "Adapter",
    "KoopmanModel",
    "BilinearModel",
    "Mpc",
    "Client",
    "ReferenceSystem",
    "PlannerService",
    "survival",
    "KoopbridgeError",
    "RemoteError",
    "BridgeTimeout",
    "GoneError",
    "InvalidInput",
    "Unsupported",
    "PROTOCOL_VERSION",
    "__version__",
]

_ArrayLike: TypeAlias = npt.ArrayLike
_Vector: TypeAlias = npt.NDArray[np.float64]
_Matrix: TypeAlias = npt.NDArray[np.float64]

PROTOCOL_VERSION: int
__version__: str

class KoopbridgeError(Exception): ...
class RemoteError(KoopbridgeError):
    code: str
    message: str
class BridgeTimeout(KoopbridgeError, TimeoutError):
    """A participant did not answer in time (also a built-in ``TimeoutError``)."""
class GoneError(KoopbridgeError): ...
class InvalidInput(KoopbridgeError): ...
class Unsupported(KoopbridgeError): ...

@disjoint_base
class Adapter:
    """Base class of simulators written in Python; implement info, reset, step; call serve."""

    def __new__(cls, *_args: Any, **_kwargs: Any) -> Self: ...
    def info(self) -> dict[str, Any]:
        """``env``, ``dt``, ``state_names``, ``input_names``, ``u_min``, ``u_max`` (required),
        ``kind``, ``version``, ``angle_indices`` (optional); any other key holds JSON-serialisable
        values and reaches clients in the ``info`` reply's ``extra`` object."""
        ...
    def reset(self, seed: int | None = None, x0: _Vector | None = None) -> _ArrayLike: ...
    def step(self, u: _Vector) -> _ArrayLike: ...
    # Optional, looked up when serving starts (not defined here): step_status(self) -> dict[str, bool] | None,
    # the flags terminated / truncated / clipped of the step just taken, sent in the step reply.
    def serve(
        self,
        *,
        session: str = "default",
        id: str = "sim0",
        connect: Sequence[str] | None = None,
        listen: Sequence[str] | None = None,
        mode: str = "peer",
        zenoh_config: str | PathLike[str] | None = None,
        free_run: bool = False,
        rate_hz: float | None = None,
        steps: int | None = None,
        seed: int | None = None,
        x0: _ArrayLike | None = None,
        wait_subscriber: float | None = None,
    ) -> dict[str, Any]: ...
    def stop(self) -> None: ...
    @property
    def serving(self) -> bool: ...
    @property
    def last_stats(self) -> dict[str, Any] | None:
        """The counters of the last ``serve()``, also one ended by Ctrl-C; ``None`` before."""
        ...

@final
class KoopmanModel:
    """A neural Koopman model z = [x, psi(x)], z+ = A z + B u, x = P z."""

    @staticmethod
    def load(path: str | PathLike[str]) -> KoopmanModel: ...
    @staticmethod
    def init(nx: int, nu: int, hidden: Sequence[int] = ..., n_mult: int = 16, seed: int = 17382) -> KoopmanModel: ...
    def save(self, path: str | PathLike[str]) -> None: ...
    @property
    def nx(self) -> int: ...
    @property
    def nu(self) -> int: ...
    @property
    def latent_dim(self) -> int: ...
    @property
    def A(self) -> _Matrix: ...
    @property
    def B(self) -> _Matrix: ...
    @property
    def P(self) -> _Matrix: ...
    @property
    def metadata(self) -> Any: ...
    @property
    def normalisation(self) -> dict[str, list[float]] | None: ...
    def encode(self, x: _ArrayLike) -> _Vector | _Matrix: ...
    def predict(self, x0: _ArrayLike, u_seq: _ArrayLike) -> _Matrix: ...

@final
class BilinearModel:
    """A bilinear Koopman model z = [x, psi(x)], z+ = A z + B u + sum_i u_i N_i z."""

    @staticmethod
    def load(path: str | PathLike[str]) -> BilinearModel: ...
    @staticmethod
    def init(nx: int, nu: int, hidden: Sequence[int] = ..., n_mult: int = 16, seed: int = 17382) -> BilinearModel: ...
    def save(self, path: str | PathLike[str]) -> None: ...
    @property
    def nx(self) -> int: ...
    @property
    def nu(self) -> int: ...
    @property
    def latent_dim(self) -> int: ...
    @property
    def A(self) -> _Matrix: ...
    @property
    def B(self) -> _Matrix: ...
    @property
    def N(self) -> list[_Matrix]: ...
    @property
    def metadata(self) -> Any: ...
    def predict(self, x0: _ArrayLike, u_seq: _ArrayLike) -> _Matrix: ...

@final
class Mpc:
    """Linear MPC on a lifted model; keyword arguments are MpcConfig fields."""

    def __new__(cls, model: KoopmanModel | str | PathLike[str], **config: Any) -> Self: ...
    def solve(self, x: _ArrayLike, reference: _ArrayLike, feedforward: _ArrayLike | None = None) -> dict[str, Any]: ...
    @property
    def horizon(self) -> int: ...

@disjoint_base
class Client:
    """A client of one koopbridge session over Zenoh."""

    def __new__(
        cls,
        session: str = "default",
        connect: Sequence[str] | None = None,
        listen: Sequence[str] | None = None,
        mode: str = "peer",
        zenoh_config: str | PathLike[str] | None = None,
    ) -> Self: ...
    @property
    def session(self) -> str: ...
    def connect_sim(self, id: str, timeout: float = 10.0) -> dict[str, Any]: ...
    def reset(self, id: str, seed: int | None = None, x0: _ArrayLike | None = None, perturbation: dict[str, Any] | None = None) -> _Vector: ...
    @overload
    def step(self, id: str, u: _ArrayLike, *, with_status: Literal[False] = False) -> tuple[int, float, _Vector]: ...
    @overload
    def step(self, id: str, u: _ArrayLike, *, with_status: Literal[True]) -> tuple[int, float, _Vector, dict[str, bool]]:
        """With ``with_status=True`` the fourth item is the step's flags ``terminated``,
        ``truncated``, ``clipped`` (all ``False`` when the simulator reported none)."""
        ...
    @overload
    def step_at(self, id: str, k: int, u: _ArrayLike, timeout: float = 10.0, *, with_status: Literal[False] = False) -> tuple[int, float, _Vector]:
        """One step request for an explicit k, no retries; a repeated (k, u) is answered from
        the adapter's cache."""
        ...
    @overload
    def step_at(
        self, id: str, k: int, u: _ArrayLike, timeout: float = 10.0, *, with_status: Literal[True]
    ) -> tuple[int, float, _Vector, dict[str, bool]]: ...
    def collect(
        self,
        id: str,
        seed: int,
        block: int,
        block_windows: int,
        steps: int,
        windows: int | None = None,
        policy: dict[str, Any] | None = None,
        timeout: float = 600.0,
    ) -> tuple[_Vector, _Vector]:
        """Block ``block`` of a collection the simulator runs itself (``collect`` request);
        returns ``(x, u)`` of shapes ``(n, steps + 1, nx)`` and ``(n, steps, nu)``."""
        ...
    def solve(
        self,
        mpc_id: str,
        x: _ArrayLike,
        reference: _ArrayLike,
        model: str = "",
        nu: int | None = None,
        timeout: float = 10.0,
        feedforward: _ArrayLike | None = None,
    ) -> dict[str, Any]: ...
    def configure_mpc(self, mpc_id: str, model: str, timeout: float = 60.0, **mpc: Any) -> dict[str, Any]:
        """Loads a model into an MPC service with MpcConfig fields (and ``offset_free``, an
        OffsetFreeConfig dict, for a bilinear model); returns its reply."""
        ...
    def submit_job(
        self,
        trainer_id: str,
        model: str,
        train: str,
        val: str,
        test: str | None = None,
        config: dict[str, Any] | None = None,
        timeout: float = 30.0,
    ) -> str:
        """Submits a training job (datasets: .npz paths or ``recording:NAME``); returns its id."""
        ...
    def job(self, trainer_id: str, job: str, timeout: float = 10.0) -> dict[str, Any]: ...
    def wait_job(self, trainer_id: str, job: str, timeout: float = 3600.0, poll: float = 0.5) -> dict[str, Any]: ...
    def fetch_model(self, name: str, dest: str | PathLike[str], timeout: float = 60.0) -> str:
        """Fetches a model from the model store into directory ``dest``; returns ``dest``."""
        ...
    def attach(self, mpc_id: str, sim: str, model: str, reference: _ArrayLike, timeout: float = 30.0) -> str: ...
    def detach(self, mpc_id: str, sim: str, timeout: float = 30.0) -> dict[str, Any]: ...
    def record_start(self, recorder_id: str, sim: str, window_steps: int | None = None, reference: _ArrayLike | None = None, timeout: float = 10.0) -> None: ...
    def record_stop(self, recorder_id: str, sim: str, name: str, timeout: float = 30.0) -> dict[str, Any]: ...
    def query(self, key: str, payload: bytes = ..., timeout: float = 10.0) -> bytes: ...
    def close(self) -> None: ...
    def __enter__(self) -> Self: ...
    def __exit__(self, _t: type[BaseException] | None, _v: BaseException | None, _tb: TracebackType | None) -> bool: ...

@final
class ReferenceSystem:
    """A built-in Rust reference system by name."""

    def __new__(cls, name: str) -> Self: ...
    @staticmethod
    def names() -> list[str]: ...
    def info(self) -> dict[str, Any]: ...
    def step(self, x: _ArrayLike, u: _ArrayLike) -> _Vector: ...

@final
class PlannerService:
    """Serves a Python planner ``plan(start, goal, dt) -> dict`` at koopbridge/{session}/planner/{id}/plan."""

    def __new__(cls, plan: Callable[[list[float], list[float], float], dict[str, Any]], nq: int) -> Self: ...
    def serve(
        self,
        *,
        session: str = "default",
        id: str = "planner0",
        connect: Sequence[str] | None = None,
        listen: Sequence[str] | None = None,
        mode: str = "peer",
        zenoh_config: str | PathLike[str] | None = None,
    ) -> dict[str, int]:
        """Serves until ``stop()`` or Ctrl-C; returns the counters ``plans``, ``errors``, ``busy``."""
        ...
    def stop(self) -> None: ...
    @property
    def serving(self) -> bool: ...

def survival(
    x: _ArrayLike,
    reference: _ArrayLike,
    terminated: Sequence[bool],
    threshold: float,
    states: Sequence[int],
    length: int | None = None,
) -> int:
    """Survival steps of the run ``x`` (with its fall flags) against ``reference``: the scenario engine's metric."""
    ...
