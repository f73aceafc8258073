"""``koopbridge.Client``: the Rust client (simulators, MPC solves, raw queries) plus the JSON
control plane of PROTOCOL.md: configuring the MPC service, training jobs, fetching models."""

from __future__ import annotations

import json
import os
import shutil
import struct
import tempfile
import time
from typing import Any

from ._native import Client as _NativeClient
from ._native import KoopbridgeError


class Client(_NativeClient):
    """A client of one koopbridge session (see ``help(koopbridge._native.Client)`` for the
    constructor, ``connect_sim``, ``reset``, ``step``, ``solve`` and ``query``)."""

    def _json(self, key: str, body: Any = None, timeout: float = 10.0) -> Any:
        payload = b"" if body is None else json.dumps(body).encode()
        return json.loads(self.query(key, payload, timeout))

    def configure_mpc(self, mpc_id: str, model: str, timeout: float = 60.0, **mpc: Any) -> dict[str, Any]:
        """Loads ``model`` into MPC service ``mpc_id`` and builds its controller once; ``mpc``
        holds MPC configuration fields (``horizon``, ``u_min``, ...). Returns the service's
        reply (``model``, ``nx``, ``nu``, ``horizon``, ``build_ms``)."""
        return self._json(f"mpc/{mpc_id}/configure", {"model": model, "mpc": mpc}, timeout)

    def submit_job(
        self,
        trainer_id: str,
        model: str,
        train: str,
        val: str,
        test: str | None = None,
        config: dict[str, Any] | None = None,
    ) -> str:
        """Submits a training job: datasets are ``.npz`` paths inside the trainer's data root
        (``koopbridge serve --data-root``; others are refused with ``forbidden``) or
        ``recording:NAME`` for a recorder's dataset. Returns the job id."""

        def ref(d: str) -> dict[str, str]:
            return {"recording": d[len("recording:"):]} if d.startswith("recording:") else {"path": os.path.abspath(d)}

        spec: dict[str, Any] = {"model": model, "train": ref(train), "val": ref(val), "config": config or {}}
        if test is not None:
            spec["test"] = ref(test)
        return self._json(f"trainer/{trainer_id}/jobs", spec)["job"]

    def job(self, trainer_id: str, job: str) -> dict[str, Any]:
        """The record of a training job (``state``, ``progress``, ``metrics``, ``error``)."""
        return self._json(f"trainer/{trainer_id}/jobs/{job}")

    def wait_job(self, trainer_id: str, job: str, timeout: float = 3600.0, poll: float = 0.5) -> dict[str, Any]:
        """Polls a job until it is done (returns its record) or failed/cancelled (raises)."""
        deadline = time.monotonic() + timeout
        while True:
            rec = self.job(trainer_id, job)
            if rec["state"] == "done":
                return rec
            if rec["state"] in ("failed", "cancelled"):
                raise KoopbridgeError(f"training job {job} on trainer '{trainer_id}' {rec['state']}: {rec.get('error')}")
            if time.monotonic() > deadline:
                raise KoopbridgeError(f"training job {job} on trainer '{trainer_id}' not done after {timeout} s (state {rec['state']})")
            time.sleep(poll)

    def fetch_model(self, name: str, dest: str, timeout: float = 60.0) -> str:
        """Fetches model ``name`` from the model store into directory ``dest`` (written under a
        temporary name, then renamed); returns ``dest``. Load it with ``KoopmanModel.load``."""
        blob = self.query(f"models/{name}", b"", timeout)
        files = parse_model_archive(blob)
        parent = os.path.dirname(os.path.abspath(dest)) or "."
        os.makedirs(parent, exist_ok=True)
        tmp = tempfile.mkdtemp(prefix=".fetch-", dir=parent)
        try:
            for fname, data in files.items():
                with open(os.path.join(tmp, fname), "wb") as f:
                    f.write(data)
            if os.path.exists(dest):
                shutil.rmtree(dest)
            os.replace(tmp, dest)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return dest


def parse_model_archive(blob: bytes) -> dict[str, bytes]:
    """The files of a model archive (PROTOCOL.md §6: ``KBM1``, u32 header length, JSON header
    with ``files: [{name, size}]``, then the files' bytes in order)."""
    if len(blob) < 8 or blob[:4] != b"KBM1":
        raise KoopbridgeError("model archive: does not start with KBM1")
    (hlen,) = struct.unpack_from("<I", blob, 4)
    if 8 + hlen > len(blob):
        raise KoopbridgeError("model archive: truncated header")
    header = json.loads(blob[8 : 8 + hlen])
    out: dict[str, bytes] = {}
    pos = 8 + hlen
    for f in header["files"]:
        name, size = f["name"], int(f["size"])
        if "/" in name or "\\" in name or name in ("", ".", ".."):
            raise KoopbridgeError(f"model archive: unsafe file name {name!r}")
        if pos + size > len(blob):
            raise KoopbridgeError(f"model archive: truncated file {name}")
        out[name] = blob[pos : pos + size]
        pos += size
    if pos != len(blob):
        raise KoopbridgeError(f"model archive: {len(blob) - pos} trailing bytes")
    return out
