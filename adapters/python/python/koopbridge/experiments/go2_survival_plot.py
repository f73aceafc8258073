"""A legged robot's survival figures (the Go2's and the G1's): a histogram of survival steps per
controller (the open-loop replay floor among them) and the joint tracking of one reference (the
state's joints, reference dashed)."""

from __future__ import annotations

import io

import numpy as np

from .dataset_npz import write_atomic

__all__ = ["histogram", "tracking"]


def _save(fig: object, path: str) -> None:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)  # type: ignore[attr-defined]
    plt.close(fig)  # type: ignore[arg-type]
    write_atomic(path, lambda f: f.write(buf.getvalue()))  # type: ignore[attr-defined]


def histogram(path: str, survivals: dict[str, list[int]], length: int, threshold: float) -> None:
    """One histogram of survival steps per controller, on shared bins over ``[0, length]``,
    each with its mean marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(survivals)
    fig, axes = plt.subplots(len(names), 1, figsize=(8, 1.9 * len(names) + 0.8), sharex=True, squeeze=False)
    bins = np.linspace(0, length, min(31, length + 1) + 0)
    for i, (ax, name) in enumerate(zip(axes[:, 0], names, strict=True)):
        s = np.asarray(survivals[name], float)
        ax.hist(s, bins=bins, color=f"C{i}", alpha=0.8)
        ax.axvline(float(s.mean()), color="k", lw=1.2, ls="--")
        ax.set_ylabel("references")
        ax.set_title(f"{name}: mean {s.mean():.1f}, median {np.median(s):.0f}, std {s.std(ddof=1) if len(s) > 1 else 0:.1f} (n = {len(s)})",
                     fontsize=9)
    axes[-1, 0].set_xlabel(f"survival steps (mean |q - q_ref| <= {threshold} rad and upright; capped at {length})")
    fig.tight_layout()
    _save(fig, path)


def tracking(path: str, ref: np.ndarray, runs: dict[str, np.ndarray], survivals: dict[str, int], dt: float,
             joint_names: list[str], q0: int = 10, robot: str = "Go2") -> None:
    """Joint positions of each run against the reference (dashed) for the joints of
    ``joint_names`` (state columns from ``q0``), each run drawn up to where it stopped, its
    survival step marked; ``robot`` names the robot in the title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    nj = len(joint_names)
    fig, axes = plt.subplots((nj + 2) // 3, 3, figsize=(14, 2.2 * ((nj + 2) // 3) + 0.6), sharex=True, squeeze=False)
    t_ref = dt * np.arange(len(ref))
    for j, ax in enumerate(axes.flat):
        if j >= nj:
            ax.axis("off")
            continue
        ax.plot(t_ref, ref[:, q0 + j], "k--", lw=1.2, label="reference" if j == 0 else None)
        for i, (name, x) in enumerate(runs.items()):
            ok = np.all(np.isfinite(x), axis=1)
            t = dt * np.arange(len(x))
            ax.plot(t[ok], x[ok, q0 + j], "-", lw=0.9, color=f"C{i}", label=name if j == 0 else None)
            s = survivals.get(name)
            if s is not None and s < len(ref) - 1:
                ax.axvline(dt * s, color=f"C{i}", lw=0.6, ls=":")
        ax.set_title(joint_names[j], fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0, 0].legend(fontsize=7, loc="best")
    for ax in axes[-1, :]:
        ax.set_xlabel("time (s)")
    fig.suptitle(f"{robot} joint tracking (rad): reference dashed; dotted lines: each run's survival step", fontsize=10)
    fig.tight_layout()
    _save(fig, path)
