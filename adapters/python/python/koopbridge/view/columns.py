"""Rows of many steps sent to Rerun as columns (``send_columns``): one call per entity for tens of
steps instead of one per entity and step, which is what keeps the viewer's CPU below the run's."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import rerun as rr

from .robots import RobotPoser

__all__ = ["BATCH", "Columns", "Times", "time_columns"]

# Rows an entity gathers before they are sent (and whenever the viewer has nothing else to do).
BATCH = 32

#: A time of a row: (timeline, "sequence" | "duration") -> value.
Times = dict[tuple[str, str], float]


def time_columns(times: dict[tuple[str, str], list[float]]) -> list[rr.TimeColumn]:
    """Rerun's time columns of queued rows: (timeline, kind) -> one value per row."""
    return [
        rr.TimeColumn(name, sequence=[int(v) for v in vs]) if kind == "sequence" else rr.TimeColumn(name, duration=vs)
        for (name, kind), vs in times.items()
    ]


@dataclass
class _Queue:
    kind: str
    times: dict[tuple[str, str], list[float]] = field(default_factory=dict)
    rows: list[Any] = field(default_factory=list)
    robot: RobotPoser | None = None


class Columns:
    """Scalars, 2D line strips and robot poses queued per entity with their times, sent as
    columns. Every row of an entity has the same shape (a state group, the inputs, a pose)."""

    def __init__(self, rec: rr.RecordingStream) -> None:
        self.rec = rec
        self._queues: dict[str, _Queue] = {}

    def scalars(self, path: str, times: Times, values: np.ndarray) -> None:
        """One row of scalars at ``times``."""
        self._add(path, "scalars", times, np.asarray(values, dtype=np.float64))

    def strips(self, path: str, times: Times, strips: np.ndarray) -> None:
        """One row of 2D line strips (``(n, points, 2)``) at ``times``."""
        self._add(path, "strips", times, np.asarray(strips, dtype=np.float64))

    def pose(self, root: str, times: Times, robot: RobotPoser, pose: tuple[np.ndarray, np.ndarray]) -> None:
        """One pose of ``robot``'s geoms under ``root`` (``RobotPoser.pose``) at ``times``."""
        self._add(root, "poses", times, pose, robot)

    def _add(self, path: str, kind: str, times: Times, row: Any, robot: RobotPoser | None = None) -> None:
        q = self._queues.setdefault(path, _Queue(kind, robot=robot))
        for key, v in times.items():
            q.times.setdefault(key, []).append(v)
        q.rows.append(row)
        if len(q.rows) >= BATCH:
            self._send(path)

    def _send(self, path: str) -> None:
        q = self._queues.pop(path)
        index = time_columns(q.times)
        if q.kind == "poses" and q.robot is not None:
            q.robot.log_poses(self.rec, path, index, q.rows)
            return
        if q.kind == "scalars":
            cols = rr.Scalars.columns(scalars=np.stack(q.rows))
        else:
            cols = rr.LineStrips2D.columns(strips=[s for r in q.rows for s in r]).partition([len(r) for r in q.rows])
        self.rec.send_columns(path, indexes=index, columns=cols)

    def flush(self) -> None:
        """Sends every queued row."""
        for path in list(self._queues):
            self._send(path)
