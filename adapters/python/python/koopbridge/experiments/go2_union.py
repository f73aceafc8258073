"""On-policy aggregation's data step: a dataset folder whose training split is the expert data's
plus the MPC's closed-loop windows (``go2_survival``'s ``onpolicy/{model}.npz``), validation and
test the expert data's unchanged, so that the retrain is one ``koopbridge train --data OUT``.

    python -m koopbridge.experiments.go2_union --data DATA --add RUN/onpolicy/MODEL.npz [--add ...] --out UNION
    koopbridge train --data UNION --out models/go2-round1 --normalise --gamma 0.99 --iterations 20000
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .dataset_npz import DatasetMeta, save_dataset_npz, write_atomic

__all__ = ["load_dataset_npz", "main", "parser", "union"]


def load_dataset_npz(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """``x``, ``u`` and the ``meta.json`` record of a dataset ``.npz`` (``dataset_npz``'s layout);
    ``ValueError`` naming the file when it is not one."""
    try:
        with zipfile.ZipFile(path) as z:
            meta = json.loads(z.read("meta.json"))
            with z.open("x.npy") as f:
                x = np.lib.format.read_array(f, allow_pickle=False)
            with z.open("u.npy") as f:
                u = np.lib.format.read_array(f, allow_pickle=False)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as e:
        raise ValueError(f"{path}: not a koopbridge dataset .npz ({e})") from e
    return x, u, meta


def _copy(src: Path, dst: Path) -> None:
    """Hard-links ``src`` to ``dst`` (a copy across file systems)."""
    if dst.exists():
        dst.unlink()
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def union(data: str, added: Sequence[str], out: str) -> dict[str, Any]:
    """Writes ``out/{train,val,test}.npz``: train = ``data``'s train then every ``added`` file's
    windows (same nx, nu, T and dt), val/test linked from ``data``. Returns the summary
    (also ``out/union.json``)."""
    src, dst = Path(data), Path(out)
    x, u, meta = load_dataset_npz(src / "train.npz")
    parts = [dict(path=str(src / "train.npz"), windows=int(len(x)), policy=meta.get("policy"))]
    xs, us = [x], [u]
    for p in added:
        xa, ua, ma = load_dataset_npz(p)
        if xa.shape[1:] != x.shape[1:] or ua.shape[1:] != u.shape[1:]:
            raise ValueError(f"{p}: windows {xa.shape[1:]}/{ua.shape[1:]} do not match the expert data's {x.shape[1:]}/{u.shape[1:]} (T+1, nx)/(T, nu)")
        if abs(float(ma.get("dt", meta["dt"])) - float(meta["dt"])) > 1e-12:
            raise ValueError(f"{p}: dt {ma.get('dt')} differs from the expert data's {meta['dt']}")
        xs.append(xa)
        us.append(ua)
        parts.append(dict(path=str(p), windows=int(len(xa)), policy=ma.get("policy")))
    dst.mkdir(parents=True, exist_ok=True)
    for split in ("val", "test"):
        for ext in (".npz", ".json"):
            if (src / f"{split}{ext}").exists():
                _copy(src / f"{split}{ext}", dst / f"{split}{ext}")
    fields = {k: meta[k] for k in ("env", "dt", "state_names", "input_names", "seed", "source")}
    policy = f"union: {meta.get('policy')} + {sum(q['windows'] for q in parts[1:])} on-policy MPC windows ({len(added)} files)"
    save_dataset_npz(str(dst / "train.npz"), np.concatenate(xs), np.concatenate(us),
                     DatasetMeta(**fields, policy=policy, pairing=meta.get("pairing", "aligned")))
    summary = dict(train=int(sum(len(a) for a in xs)), parts=parts, val_test=str(src))
    write_atomic(str(dst / "union.json"), lambda f: f.write(json.dumps(summary, indent=2).encode()))  # type: ignore[attr-defined]
    return summary


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m koopbridge.experiments.go2_union``."""
    p = argparse.ArgumentParser(prog="python -m koopbridge.experiments.go2_union", description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="the expert dataset folder (train.npz, val.npz, test.npz)")
    p.add_argument("--add", action="append", default=[], metavar="NPZ", help="on-policy windows to add to the training split (repeatable)")
    p.add_argument("--out", required=True, help="the union dataset folder to write")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Writes the union; returns the exit code (2: bad input)."""
    a = parser().parse_args(argv)
    try:
        s = union(a.data, a.add, a.out)
    except (OSError, ValueError, KeyError) as e:
        print(f"go2_union: {e}", file=sys.stderr)
        return 2
    print(json.dumps({"train": s["train"], "added": [q["windows"] for q in s["parts"][1:]]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
