"""A run's ``report.json`` as the experiments' hooks extend it: one key added, atomically."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .dataset_npz import write_atomic

__all__ = ["update_report"]


def update_report(path: Path, key: str, value: dict[str, Any]) -> None:
    """Adds ``key: value`` to the JSON object in ``path``, atomically."""
    report = json.loads(path.read_text())
    report[key] = value
    write_atomic(str(path), lambda f: f.write(json.dumps(report, indent=2).encode()))  # type: ignore[attr-defined]
