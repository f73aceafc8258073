"""Writes windows as the dataset ``.npz`` that ``koopbridge train --data DIR`` reads (members
``x.npy``, ``u.npy``, ``meta.json``, stored uncompressed, plus the ``<stem>.json`` sidecar; the
layout of ``koopman/src/data/npz.rs``), each file atomically."""

from __future__ import annotations

import json
import os
import tempfile
import zipfile
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from koopbridge.collect import Windows

__all__ = ["DatasetMeta", "load_block", "save_dataset_npz", "write_atomic"]

EPOCH = (1980, 1, 1, 0, 0, 0)


@dataclass(frozen=True)
class DatasetMeta:
    """The metadata fields of the Rust ``DatasetMeta`` (``koopman::data``)."""

    env: str
    dt: float
    state_names: list[str]
    input_names: list[str]
    seed: int
    source: str
    policy: str
    pairing: str = "aligned"


def write_atomic(path: str, write: Callable[[object], None]) -> None:
    """Calls ``write(file)`` on a temporary file beside ``path``, then renames it over ``path``."""
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=folder)
    umask = os.umask(0)
    os.umask(umask)
    try:
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp's 0600 would outlive the rename
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def save_dataset_npz(path: str, x: np.ndarray, u: np.ndarray, meta: DatasetMeta) -> None:
    """Writes ``x`` ``(n, T+1, nx)`` and ``u`` ``(n, T, nu)`` (as ``<f8``) with ``meta`` to
    ``path`` and the same JSON to the sidecar ``path`` with ``.json``; both atomically."""
    x = np.ascontiguousarray(x, dtype="<f8")
    u = np.ascontiguousarray(u, dtype="<f8")
    if x.ndim != 3 or u.ndim != 3 or u.shape[0] != x.shape[0] or x.shape[1] != u.shape[1] + 1:
        raise ValueError(f"dataset shapes x {x.shape}, u {u.shape}: expected (n, T+1, nx) and (n, T, nu)")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u))):
        raise ValueError("dataset values must be finite")
    if len(meta.state_names) != x.shape[2] or len(meta.input_names) != u.shape[2]:
        raise ValueError("state/input names do not match nx/nu")
    n, t1, nx = x.shape
    record = dict(n=n, steps=t1 - 1, nx=nx, nu=u.shape[2], **asdict(meta))
    meta_json = json.dumps(record, indent=2).encode()

    def write(f: object) -> None:
        # Fixed member dates (as the Rust writer): the same data gives the same bytes.
        with zipfile.ZipFile(f, "w", compression=zipfile.ZIP_STORED) as z:  # type: ignore[arg-type]
            for name, arr in (("x.npy", x), ("u.npy", u)):
                with z.open(zipfile.ZipInfo(name, EPOCH), "w", force_zip64=True) as m:
                    np.lib.format.write_array(m, arr, allow_pickle=False)
            z.writestr(zipfile.ZipInfo("meta.json", EPOCH), meta_json)

    write_atomic(path, write)
    write_atomic(os.path.splitext(path)[0] + ".json", lambda f: f.write(meta_json))  # type: ignore[attr-defined]


def save_splits(out: str, x: np.ndarray, u: np.ndarray, cuts: dict[str, tuple[int, int]], info: Any, seed: int, source: str,
                policy: str) -> None:
    """Writes ``out/{name}.npz`` for each ``name: (lo, hi)`` window range of ``x``/``u``, with
    the metadata of the simulator ``info`` (``SimInfo``: env, dt, names) and ``seed``,
    ``source``, ``policy``."""
    meta = DatasetMeta(env=info.env, dt=info.dt, state_names=list(info.state_names), input_names=list(info.input_names),
                       seed=seed, source=source, policy=policy)
    for name, (lo, hi) in cuts.items():
        save_dataset_npz(os.path.join(out, f"{name}.npz"), x[lo:hi], u[lo:hi], meta)


def load_block(path: str, seed: int, start: int, n: int, T: int) -> Windows | None:
    """The block at ``path`` (a resumable collection's block of windows) if it exists and is the one
    asked for, else None."""
    try:
        with np.load(path) as z:
            w = Windows(x=z["x"], u=z["u"], seed=int(z["seed"]), start=int(z["start"]), reset_seeds=z["reset_seeds"])
    except (OSError, ValueError, KeyError):
        return None
    if (w.seed, w.start, w.x.shape[0], w.u.shape[1]) != (seed, start, n, T):
        return None
    return w
