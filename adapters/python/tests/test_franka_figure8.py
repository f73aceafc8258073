"""Figure-8 smoke test through the bridge: a small Franka dataset, EDMD fitted by the CLI, scored
by ``koopbridge run`` of a ``figure8_models`` scenario (the MuJoCo adapter in lockstep, the MPC
service deciding every step, SPEC's observation noise); the tracking error is finite and below the
zero-input error. Plus the task's pieces against independent computations."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from conftest import koopbridge_binary_or_skip
from koopbridge.adapters.mujoco.ik import figure8
from koopbridge.adapters.mujoco.sim import FrankaSimulator
from koopbridge_experiments import figure8_models, franka_data
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
    # The scenario of models trained elsewhere: no collection, the engine's closed loops.
    sc = tmp_path / "figure8.toml"
    assert figure8_models.main(["--model", f"franka-edmd={model}", "--out", str(sc), "--steps", "251"]) == 0
    out = tmp_path / "run"
    r = subprocess.run([str(exe), "run", str(sc), "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    rows = {c["label"]: c for c in report["controls"]}
    assert list(rows) == ["franka-edmd", "zero-input", "joint-follower"]
    errors = report["figure8"]["errors"]
    mpc = rows["franka-edmd"]
    assert len(mpc["u"]) == len(rows["zero-input"]["u"]) == 250
    assert np.isfinite(errors["franka-edmd"]) and errors["franka-edmd"] < errors["zero-input"], errors
    assert mpc["solve_median_us"] > 0 and mpc["observation_noise"]["sigma"] == 0.01
    # The error is SPEC's, recomputed here from the recorded end-effector path (the true states:
    # the noise is only what the MPC saw).
    x = np.asarray(mpc["x"])
    assert tracking_error(x[:, :3], figure8(251)) == pytest.approx(errors["franka-edmd"], rel=1e-6)
    assert np.all(np.abs(np.asarray(mpc["u"])) <= 0.3 + 1e-9)
    assert (out / "figure8.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_models_scenario_refuses_bad_rows(tmp_path, capsys):
    out = str(tmp_path / "s.toml")
    for bad in (["--model", "Bad Name=x"], ["--model", "zero-input=x"], ["--model", "noequals"]):
        assert figure8_models.main([*bad, "--out", out]) == 2, bad
    assert "figure8_models:" in capsys.readouterr().err
