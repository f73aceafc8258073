"""An exact-restore memory for MuJoCo simulators: the full integration state (and whatever the
simulator keeps outside MuJoCo) of the last states it returned, keyed by the returned state's
bytes, so that ``reset(x0=x)`` of one of them continues bit for bit."""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import numpy as np

__all__ = ["StateMemory"]


class StateMemory:
    """The last ``capacity`` states (least recently remembered forgotten first); ``capacity`` 0
    remembers nothing."""

    def __init__(self, mujoco: Any, model: Any, capacity: int) -> None:
        self._mj, self._model = mujoco, model
        self.capacity = int(capacity)
        self._size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_INTEGRATION)
        self._saved: OrderedDict[bytes, tuple[np.ndarray, Any]] = OrderedDict()

    def __len__(self) -> int:
        return len(self._saved)

    def remember(self, x: np.ndarray, data: Any, extra: Any = None) -> None:
        """Keeps ``data``'s integration state and ``extra`` (copied by the caller if mutable)
        under the state ``x``."""
        if self.capacity <= 0:
            return
        buf = np.empty(self._size)
        self._mj.mj_getState(self._model, data, buf, self._mj.mjtState.mjSTATE_INTEGRATION)
        key = x.tobytes()
        self._saved[key] = (buf, extra)
        self._saved.move_to_end(key)
        while len(self._saved) > self.capacity:
            self._saved.popitem(last=False)

    def lookup(self, x: np.ndarray) -> tuple[np.ndarray, Any] | None:
        """The integration state and extra kept under ``x``, or None."""
        return self._saved.get(x.tobytes())

    def apply(self, saved: tuple[np.ndarray, Any], data: Any) -> Any:
        """Writes a looked-up integration state into ``data`` (then ``mj_forward``); returns its extra."""
        mj = self._mj
        mj.mj_setState(self._model, data, saved[0], mj.mjtState.mjSTATE_INTEGRATION)
        mj.mj_forward(self._model, data)
        return saved[1]
