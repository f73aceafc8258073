"""The Franka SPEC dataset command: what it writes is what `koopbridge train`/`eval` read, it is
deterministic by seed whatever the block size or process count, and it resumes from its blocks."""

from __future__ import annotations

import json
import subprocess
import zipfile

import numpy as np

from conftest import koopbridge_binary_or_skip
from koopbridge.adapters.mujoco.sim import FrankaSimulator
from koopbridge.collect import UniformPolicy
from koopbridge_experiments import franka_data


def _load(path):
    with zipfile.ZipFile(path) as z:
        assert sorted(z.namelist()) == ["meta.json", "u.npy", "x.npy"]
        assert all(i.compress_type == zipfile.ZIP_STORED for i in z.infolist())
        meta = json.loads(z.read("meta.json"))
    with np.load(path) as d:
        return d["x"], d["u"], meta


def test_splits_match_the_simulator_window_by_window(tmp_path):
    out = tmp_path / "d"
    assert franka_data.main(["--out", str(out), "--windows", "45", "--block", "7", "--procs", "2"]) == 0
    xs, us = {}, {}
    for name, n in (("train", 35), ("val", 5), ("test", 5)):
        x, u, meta = _load(out / f"{name}.npz")
        assert x.shape == (n, 16, 17) and u.shape == (n, 15, 7)
        assert (meta["n"], meta["steps"], meta["nx"], meta["nu"], meta["seed"], meta["pairing"]) == (n, 15, 17, 7, 42, "aligned")
        assert meta["state_names"][:4] == ["ee_x", "ee_y", "ee_z", "q1"] and meta["dt"] == 0.02
        assert json.loads((out / f"{name}.json").read_text()) == meta
        assert np.all(np.abs(u) <= 0.12)
        xs[name], us[name] = x, u
    assert not (out / ".blocks").exists()
    # Independently: windows 35..39 (val) from a fresh simulator, stepped one by one.
    sim = FrankaSimulator()
    w = sim.collect(UniformPolicy((-0.12,), (0.12,)), 42, 5, 15, start=35)
    np.testing.assert_array_equal(w.x, xs["val"])
    x = [sim.reset(seed=int(w.reset_seeds[0]))]
    for t in range(15):
        x.append(sim.step(w.u[0, t]))
    np.testing.assert_array_equal(np.array(x), xs["val"][0])
    # Starts: home + U(±0.2) within the joint limits, at rest.
    q0 = xs["train"][:, 0, 3:10]
    assert np.all(np.abs(q0 - sim.home) <= 0.2 + 1e-12) and np.all(xs["train"][:, 0, 10:] == 0)


def test_same_bytes_for_any_block_size_and_resume(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    assert franka_data.main(["--out", str(a), "--windows", "18", "--block", "18"]) == 0
    assert franka_data.main(["--out", str(b), "--windows", "18", "--block", "4", "--keep-blocks"]) == 0
    for name in ("train", "val", "test"):
        assert (a / f"{name}.npz").read_bytes() == (b / f"{name}.npz").read_bytes()
    # Resume: a lost block is collected again, the others are reused (their files untouched).
    blocks = sorted((b / ".blocks").glob("block-*.npz"))
    assert len(blocks) == 5
    kept = blocks[0].stat().st_mtime_ns
    blocks[2].unlink()
    (b / "train.npz").unlink()
    assert franka_data.main(["--out", str(b), "--windows", "18", "--block", "4", "--keep-blocks"]) == 0
    assert blocks[0].stat().st_mtime_ns == kept
    assert (a / "train.npz").read_bytes() == (b / "train.npz").read_bytes()


def test_bad_sizes_exit_2(tmp_path):
    assert franka_data.main(["--out", str(tmp_path / "x"), "--windows", "9", "--train", "9"]) == 2


def test_koopbridge_eval_reads_the_splits(tmp_path):
    exe = koopbridge_binary_or_skip()
    out = tmp_path / "d"
    assert franka_data.main(["--out", str(out), "--windows", "90"]) == 0
    model = tmp_path / "edmd"
    r = subprocess.run([str(exe), "train", "--model", "edmd", "--data", str(out), "--out", str(model), "--json"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    metrics = json.loads(r.stdout.strip().splitlines()[-1])
    assert metrics["env"] == "franka-panda" and metrics["train_samples"] == 70
    assert np.isfinite(metrics["test_prediction_error"])
    r = subprocess.run([str(exe), "eval", "--model", str(model), "--data", str(out / "test.npz"), "--json"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


def test_from_blocks_writes_the_train_prefix_present(tmp_path):
    full, part = tmp_path / "full", tmp_path / "part"
    assert franka_data.main(["--out", str(full), "--windows", "36", "--block", "4", "--keep-blocks"]) == 0
    (full / ".blocks" / "block-0000008.npz").unlink()  # train windows 8..11 missing: prefix is 0..7
    args = ["--out", str(part), "--windows", "36", "--block", "4", "--from-blocks", str(full / ".blocks")]
    assert franka_data.main(args) == 0
    x_full, _, _ = _load(full / "train.npz")
    x_part, _, meta = _load(part / "train.npz")
    assert meta["n"] == 8
    np.testing.assert_array_equal(x_part, x_full[:8])
    for name in ("val", "test"):
        assert (full / f"{name}.npz").read_bytes() == (part / f"{name}.npz").read_bytes()
    (full / ".blocks" / "block-0000032.npz").unlink()  # a test block
    assert franka_data.main(args) == 1
