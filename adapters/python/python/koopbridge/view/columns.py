"""Rows of many steps sent to Rerun as columns (``send_columns``): one call per entity for tens of
steps instead of one per entity and step, which is what keeps the viewer's CPU below the run's."""

from __future__ import annotations

from typing import Any

import numpy as np
import rerun as rr

__all__ = ["Columns", "BATCH"]

# Rows an entity gathers before they are sent (and whenever the viewer has nothing else to do).
BATCH = 32

#: A time of a row: (timeline, "sequence" | "duration") -> value.
Times = dict[tuple[str, str], float]


class Columns:
    """Scalars and 2D line strips queued per entity with their times, sent as columns."""

    def __init__(self, rec: rr.RecordingStream) -> None:
        self.rec = rec
        self._rows: dict[str, tuple[str, dict[tuple[str, str], list[float]], list[Any]]] = {}

    def scalars(self, path: str, times: Times, values: np.ndarray) -> None:
        """One row of scalars (a fixed count per entity) at ``times``."""
        self._add(path, "scalars", times, np.asarray(values, dtype=np.float64))

    def strips(self, path: str, times: Times, strips: np.ndarray) -> None:
        """One row of 2D line strips (``(n, points, 2)``) at ``times``."""
        self._add(path, "strips", times, np.asarray(strips, dtype=np.float64))

    def _add(self, path: str, kind: str, times: Times, row: Any) -> None:
        _, t, rows = self._rows.setdefault(path, (kind, {}, []))
        for key, v in times.items():
            t.setdefault(key, []).append(v)
        rows.append(row)
        if len(rows) >= BATCH:
            self._send(path)

    def _send(self, path: str) -> None:
        kind, times, rows = self._rows.pop(path)
        index = [
            rr.TimeColumn(name, sequence=[int(v) for v in vs]) if how == "sequence" else rr.TimeColumn(name, duration=vs) for (name, how), vs in times.items()
        ]
        if kind == "scalars":
            if len({len(r) for r in rows}) != 1:  # rows of several lengths: sent one by one
                self._send_rows(path, times, rows)
                return
            cols = rr.Scalars.columns(scalars=np.stack(rows))
        else:
            cols = rr.LineStrips2D.columns(strips=[s for r in rows for s in r]).partition([len(r) for r in rows])
        self.rec.send_columns(path, indexes=index, columns=cols)

    def _send_rows(self, path: str, times: dict[tuple[str, str], list[float]], rows: list[Any]) -> None:
        for i, r in enumerate(rows):
            for (name, how), vs in times.items():
                if how == "sequence":
                    self.rec.set_time(name, sequence=int(vs[i]))
                else:
                    self.rec.set_time(name, duration=vs[i])
            self.rec.log(path, rr.Scalars(r))

    def flush(self) -> None:
        """Sends every queued row."""
        for path in list(self._rows):
            self._send(path)
