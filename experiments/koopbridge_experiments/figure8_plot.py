"""The figure-8 report's picture: end-effector paths against the figure-8 in the y–z plane and
the (y, z) deviation over time, one line per controller (matplotlib, Agg; imported here only)."""

from __future__ import annotations

import io
from collections.abc import Mapping

import numpy as np

from .dataset_npz import write_atomic
from .figure8_ref import SKIP, Figure8, tracking_error

__all__ = ["plot"]


def plot(path: str, task: Figure8, paths: Mapping[str, np.ndarray]) -> None:
    """Writes the PNG to ``path`` atomically: ``paths`` maps each row's name to its end-effector
    path ``(n, 3)``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5))
    ax1.plot(task.targets[:, 1], task.targets[:, 2], "k--", lw=1.5, label="figure-8 target")
    t = 0.02 * np.arange(len(task.targets))
    for name, ee in paths.items():
        err = tracking_error(ee, task.targets[: len(ee)])
        ax1.plot(ee[:, 1], ee[:, 2], lw=1, label=f"{name} (error {err:.3f})")
        dev = np.linalg.norm(ee[:, 1:3] - task.targets[: len(ee), 1:3], axis=1)
        # Log scale: the controllers worth comparing sit orders of magnitude below zero input.
        ax2.semilogy(t[: len(ee)], np.maximum(dev, 1e-6), lw=1, label=name)
    ax1.set_xlabel("y (m)")
    ax1.set_ylabel("z (m)")
    ax1.set_aspect("equal", adjustable="datalim")
    ax1.set_title("end-effector path, y–z plane")
    ax1.legend(fontsize=8)
    ax2.axvline(0.02 * SKIP, color="grey", lw=0.8, ls=":")
    ax2.set_xlabel("time (s)")
    ax2.set_ylabel("|(y, z) deviation| (m, log scale)")
    ax2.set_title(f"deviation per step (error counts t > {0.02 * SKIP:g} s)")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    write_atomic(path, lambda f: f.write(buf.getvalue()))  # type: ignore[attr-defined]
