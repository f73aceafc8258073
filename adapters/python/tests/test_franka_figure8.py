"""Figure-8 smoke test through the bridge: a small Franka dataset, EDMD fitted by the CLI, the
MuJoCo adapter (child process) in lockstep with the Rust MPC service (child process) deciding
every step; the tracking error is finite and below the zero-input error. Plus the task's pieces
against independent computations."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from conftest import koopbridge_binary_or_skip
from koopbridge.adapters.mujoco.ik import figure8
from koopbridge.adapters.mujoco.sim import FrankaSimulator
from koopbridge_experiments import figure8 as fig8
from koopbridge_experiments import franka_data
from koopbridge_experiments.figure8_ref import joint_p_command, references, tracking_error


def test_references_start_offset_and_error_metric():
    sim = FrankaSimulator()
    task = references(sim, 120)
    np.testing.assert_allclose(task.targets, figure8(120))
    assert task.ik_error < 1e-5
    # The start: the first target + (0, 0.01, 0.043), at rest, by forward kinematics of its q.
    np.testing.assert_allclose(sim.ee_position(task.x0[3:10]), task.targets[0] + [0, 0.01, 0.043], atol=1e-5)
    np.testing.assert_allclose(task.x0[:3], sim.ee_position(task.x0[3:10]), atol=0)
    assert np.all(task.x0[10:] == 0) and np.all(task.x[:, 10:] == 0)
    # The reference window is x_{k+1..k+H}, the last point held.
    np.testing.assert_array_equal(task.reference_window(0, 3), task.x[1:4])
    np.testing.assert_array_equal(task.reference_window(118, 3), task.x[[119, 119, 119]])
    # Error: sqrt of the summed squared (y, z) deviations after step 100, written out.
    ee = task.targets + np.random.default_rng(0).normal(0, 0.01, task.targets.shape)
    want = np.sqrt(sum((ee[k, 1] - task.targets[k, 1]) ** 2 + (ee[k, 2] - task.targets[k, 2]) ** 2 for k in range(100, 120)))
    assert tracking_error(ee, task.targets) == pytest.approx(want, rel=1e-12)
    np.testing.assert_array_equal(joint_p_command(np.zeros(7), np.full(7, 0.2), 5.0, 0.3), np.full(7, 0.3))


def test_figure8_through_the_bridge_beats_zero_input(tmp_path):
    exe = koopbridge_binary_or_skip()
    data = tmp_path / "data"
    assert franka_data.main(["--out", str(data), "--windows", "900"]) == 0
    model = tmp_path / "store" / "franka-edmd"
    r = subprocess.run([str(exe), "train", "--model", "edmd", "--data", str(data), "--out", str(model)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "run"
    assert fig8.main(["--model", str(model), "--out", str(out), "--steps", "251", "--baselines", "zero"]) == 0
    report = json.loads((out / "report.json").read_text())
    mpc, zero = report["controllers"]["mpc"], report["controllers"]["zero"]
    assert mpc["steps"] == zero["steps"] == 250
    assert np.isfinite(mpc["error"]) and mpc["error"] < zero["error"], report
    assert mpc["solve"]["median_us"] > 0 and mpc["statuses"]
    # The saved path is the one the error was computed from.
    with np.load(out / "paths.npz") as p:
        assert tracking_error(p["x_mpc"][:, :3], p["targets"]) == pytest.approx(mpc["error"], rel=1e-12)
        assert np.all(np.abs(p["u_mpc"]) <= 0.3 + 1e-9)
    assert (out / "figure8.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_model_folder_exits_2(tmp_path):
    assert fig8.main(["--model", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")]) == 2
    bad = tmp_path / "Bad Name"
    bad.mkdir()
    (bad / "config.json").write_text("{}")
    assert fig8.main(["--model", str(bad), "--out", str(tmp_path / "o")]) == 2
