"""The Kinova data-collection script at a tiny budget: a koopbridge dataset that the Rust reader
accepts, windows that are pieces of executed plans, metadata naming goals, seeds and solvers,
and goals that differ between splits."""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile

import numpy as np

from conftest import koopbridge_binary
from koopbridge.adapters.drake.collect import goal_seed
from koopbridge.adapters.drake.model import VELOCITY_LIMITS


def _load(path):
    with zipfile.ZipFile(path) as z:
        names = set(z.namelist())
        x = np.load(z.open("x.npy"))
        u = np.load(z.open("u.npy"))
        plan = np.load(z.open("plan.npy"))
        meta = json.loads(z.read("meta.json"))
    assert names == {"x.npy", "u.npy", "plan.npy", "session.npy", "meta.json"}
    return x, u, plan, meta


def test_collect_script_writes_a_dataset(tmp_path):
    out = tmp_path / "kinova"
    cmd = [sys.executable, "-m", "koopbridge.adapters.drake_collect", "--out", str(out), "--goals", "2", "--seed", "7"]
    r = subprocess.run(cmd + ["--split", "test"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    x, u, plan, meta = _load(out / "test-000.npz")
    assert json.loads((out / "test-000.json").read_text()) == meta
    n = x.shape[0]
    assert n > 50 and x.shape == (n, 16, 14) and u.shape == (n, 15, 7) and plan.shape == (n,)
    assert (meta["n"], meta["steps"], meta["nx"], meta["nu"], meta["dt"]) == (n, 15, 14, 7, 0.001)
    assert meta["pairing"] == "aligned" and meta["split"] == "test" and meta["goal_seed"] == goal_seed(7, "test", 0)
    assert len(meta["goals"]) == 2 and meta["planner"]["solvers"][0] == "snopt"
    assert [p["name"] for p in meta["plans"][0]["passes"]] == ["kinematic", "collision"]
    assert sum(p["windows"] for p in meta["plans"]) == n
    assert np.all(np.abs(u) <= VELOCITY_LIMITS + 1e-12)
    # Each window starts at rest only if it is the first of a plan; inside a window the
    # positions move by about the commanded velocity times dt (the arm tracks its commands).
    dq = np.diff(x[:, :, :7], axis=1)
    assert np.max(np.abs(dq - u * 0.001)) < 2e-4
    # The Rust dataset reader accepts the file.
    kb = koopbridge_binary()
    if kb is not None:
        info = subprocess.run([str(kb), "data", "info", str(out / "test-000.npz")], capture_output=True, text=True)
        assert info.returncode == 0 and f"x [{n}, 16, 14]" in info.stdout, info.stdout + info.stderr
    # Another split draws other goals.
    r = subprocess.run(cmd + ["--split", "val", "--goals", "1"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    _, _, _, val = _load(out / "val-000.npz")
    assert val["goal_seed"] != meta["goal_seed"] and val["goals"][0] not in meta["goals"]
    # Sessions combine into the file `koopbridge train --data` reads, cut to a window budget.
    r = subprocess.run(cmd + ["--split", "test", "--sessions", "0", "--combine", "--max-windows", "50"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    cx, cu, cplan, cmeta = _load(out / "test.npz")
    assert cx.shape == (50, 16, 14) and cmeta["n"] == 50 and cmeta["sessions"][0]["goals"] == meta["goals"]
    rows = {w.tobytes() for w in x}
    assert all(w.tobytes() in rows for w in cx)  # windows of the session, none made up
