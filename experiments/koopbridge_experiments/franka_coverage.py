"""How much of a joint reference (the figure-8's, ``figure8_scenario reference``) lies inside the
range a Franka dataset covers (issue 26 §4): per joint the data's min/max position over every
state of the training windows against the reference's min/max, the fraction of reference samples
inside each joint's range, inside the joint-wise box (all seven at once), the largest distance
by which the reference leaves the range, and the distance (rad, Euclidean over the seven joints)
from each reference sample to the nearest data state (median and largest: how densely the data
cover the path, which the box alone does not say).

    python -m koopbridge_experiments.franka_coverage --data DIR --reference F.npy [--json OUT.json]

``DIR`` holds ``train.npz`` (``koopbridge train --data`` layout, ``x (n, T+1, nx)``) or is such a
file; the joint positions are the state's ``q1..q7`` (found by the dataset's ``state_names``,
else columns 3..9 of the ``ee,q,qd`` layout); the reference is a ``(steps, nx)`` ``.npy`` in the
same layout.
"""

from __future__ import annotations

import argparse
import json
import sys
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["coverage", "joint_columns", "load_states", "main", "parser"]


def load_states(data: Path) -> tuple[np.ndarray, list[str]]:
    """Every state of the windows in ``data`` (a folder with ``train.npz``, or an ``.npz``) as
    ``(n·(T+1), nx)``, and the dataset's state names (empty when it has none)."""
    path = data / "train.npz" if data.is_dir() else data
    if not path.is_file():
        raise ValueError(f"{path} is not a dataset file (expected DIR/train.npz or an .npz)")
    with np.load(path) as z:
        x = np.asarray(z["x"], dtype=float)
    names: list[str] = []
    with zipfile.ZipFile(path) as zf:
        if "meta.json" in zf.namelist():
            names = list(json.loads(zf.read("meta.json")).get("state_names", []))
    if x.ndim != 3:
        raise ValueError(f"{path}: x has shape {x.shape}, expected (n, T+1, nx)")
    return x.reshape(-1, x.shape[2]), names


def joint_columns(names: Sequence[str], nx: int) -> list[int]:
    """The columns of the seven joint positions: named ``q1..q7`` (or ``q0..q6``) in ``names``,
    else 3..9 of the 17-D ``ee,q,qd`` state, else 0..6 of the 14-D ``q,qd`` state."""
    for first in (1, 0):
        want = [f"q{i}" for i in range(first, first + 7)]
        if all(w in names for w in want):
            return [list(names).index(w) for w in want]
    if nx == 17:
        return list(range(3, 10))
    if nx == 14:
        return list(range(7))
    raise ValueError(f"cannot find the joint positions in a {nx}-D state (names {list(names)})")


def coverage(states: np.ndarray, reference: np.ndarray, cols: Sequence[int]) -> dict[str, Any]:
    """Coverage of the reference's joint positions by the data's per-joint range (see the
    module doc). ``states`` ``(n, nx)``, ``reference`` ``(steps, nx)``."""
    if reference.ndim != 2 or reference.shape[1] != states.shape[1]:
        raise ValueError(f"reference {reference.shape} and data states {states.shape} differ in width")
    q, r = states[:, cols], reference[:, cols]
    lo, hi = q.min(axis=0), q.max(axis=0)
    inside = (r >= lo) & (r <= hi)
    outside_by = np.maximum(lo - r, r - hi).clip(min=0.0).max(axis=0)
    nn = np.empty(len(r))
    for i in range(0, len(r), 256):  # |a - b|² = |a|² - 2 a·b + |b|², in blocks of reference samples
        d2 = (r[i : i + 256] ** 2).sum(1)[:, None] - 2.0 * r[i : i + 256] @ q.T + (q**2).sum(1)[None, :]
        nn[i : i + 256] = np.sqrt(d2.min(axis=1).clip(min=0.0))
    return dict(
        joints=[f"q{i + 1}" for i in range(len(cols))],
        data_min=lo.tolist(),
        data_max=hi.tolist(),
        reference_min=r.min(axis=0).tolist(),
        reference_max=r.max(axis=0).tolist(),
        fraction_inside_per_joint=inside.mean(axis=0).tolist(),
        fraction_inside_box=float(inside.all(axis=1).mean()),
        max_outside_rad=outside_by.tolist(),
        nearest_data_rad_median=float(np.median(nn)),
        nearest_data_rad_max=float(nn.max()),
        states=int(len(states)),
        reference_steps=int(len(reference)),
    )


def _markdown(name: str, c: dict[str, Any]) -> str:
    rows = [f"{name}: {c['states']} states, {100 * c['fraction_inside_box']:.1f} % of the reference inside the joint-wise box, "
            f"nearest data state median {c['nearest_data_rad_median']:.3f} rad, largest {c['nearest_data_rad_max']:.3f} rad",
            "| joint | data min | data max | ref min | ref max | ref inside | ref outside by (rad) |", "|---|---|---|---|---|---|---|"]
    for i, j in enumerate(c["joints"]):
        rows.append(f"| {j} | {c['data_min'][i]:.3f} | {c['data_max'][i]:.3f} | {c['reference_min'][i]:.3f} | {c['reference_max'][i]:.3f} "
                    f"| {100 * c['fraction_inside_per_joint'][i]:.1f} % | {c['max_outside_rad'][i]:.3f} |")
    return "\n".join(rows)


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.franka_coverage", description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, action="append", help="dataset folder (with train.npz) or .npz; repeatable")
    p.add_argument("--reference", required=True, help="the joint reference .npy (figure8_scenario reference --out F.npy)")
    p.add_argument("--json", help="also write the figures here")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: prints a Markdown table per dataset."""
    a = parser().parse_args(argv)
    try:
        ref = np.load(a.reference)
        out = {}
        for d in a.data:
            states, names = load_states(Path(d))
            out[d] = coverage(states, ref, joint_columns(names, states.shape[1]))
            print(_markdown(d, out[d]) + "\n")
        if a.json:
            Path(a.json).write_text(json.dumps(out, indent=2))
    except (OSError, ValueError, KeyError) as e:
        print(f"franka_coverage: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
