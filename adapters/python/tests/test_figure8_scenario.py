"""The figure-8 steps of scenarios/franka-figure8.toml: the reference file is the task's
full-state reference, the scenario's x0 is the task's start, and the report step scores a closed
loop with SPEC's error, written out independently, for trajectories whose error is known (the
in-process baselines run again as the "closed loop")."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

from conftest import ROOT
from koopbridge.adapters.mujoco.ik import figure8
from koopbridge_experiments import figure8_scenario as f8s
from koopbridge_experiments.figure8_ref import joint_p_command, references

SCENARIO = ROOT / "scenarios" / "franka-figure8.toml"
U_LIMIT = 1.0


def test_reference_file_is_the_tasks_full_state_reference(tmp_path):
    out = tmp_path / "sub" / "ref.npy"
    assert f8s.main(["reference", "--u-limit", "1.0", "--steps", "130", "--out", str(out)]) == 0
    ref = np.load(out)
    assert ref.dtype == np.float64 and ref.shape == (130, 17)
    np.testing.assert_allclose(ref[:, :3], figure8(130), atol=0)  # ee targets (SPEC's lemniscate)
    assert np.all(ref[:, 10:] == 0)  # q̇_ref = 0
    sim = f8s.simulator(u_limit=U_LIMIT)
    for k in (0, 64, 129):  # the joint references reach the targets
        np.testing.assert_allclose(sim.ee_position(ref[k, 3:10]), ref[k, :3], atol=1e-5)


def test_scenario_x0_is_the_tasks_start_and_the_clip_is_the_same_everywhere(capsys):
    sc = tomllib.loads(SCENARIO.read_text())
    assert f8s.main(["x0", "--u-limit", "1.0"]) == 0
    want = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(sc["control"]["x0"], want, atol=1e-9)
    (sim,) = sc["sims"]
    assert sim["command"][sim["command"].index("--u-limit") + 1] == "1.0"
    assert all("--u-limit 1.0" in h["command"] for h in sc["hooks"])
    assert len(sc["control"]["mpc"]["q"]) == 17


@pytest.mark.parametrize("as_list", [False, True])
def test_report_scores_a_closed_loop_with_specs_error(tmp_path, as_list):
    steps = 160
    sim = f8s.simulator(u_limit=U_LIMIT)
    task = references(sim, steps)
    # A "closed loop" that is the greedy joint follower, run here independently of the module.
    x = sim.reset(x0=task.x0)
    xs, us = [x], []
    for k in range(steps - 1):
        u = joint_p_command(x[3:10], task.q[k + 1], 50.0, U_LIMIT)
        x = sim.step(u)
        xs.append(x)
        us.append(u)
    xs = np.array(xs)
    entry = dict(sim="arm0", model="m", x=xs.tolist(), u=np.array(us).tolist())
    (tmp_path / "report.json").write_text(json.dumps(dict(name="t", control=[entry] if as_list else entry)))
    # The closed loop is not a model's: no error-state row (it needs the run's model).
    assert f8s.main(["report", "--u-limit", "1.0", "--out", str(tmp_path), "--no-error-state"]) == 0
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["name"] == "t" and rep["control"]  # the orchestrator's report is kept
    e = rep["figure8"]["errors"]
    want = np.sqrt(sum((xs[k, 1] - task.targets[k, 1]) ** 2 + (xs[k, 2] - task.targets[k, 2]) ** 2 for k in range(100, steps)))
    assert e["koopman-mpc"] == pytest.approx(want, rel=1e-5)
    assert e["joint-follower"] == pytest.approx(e["koopman-mpc"], rel=1e-5)  # the same controller
    assert e["zero-input"] > 5 * e["joint-follower"]
    assert (tmp_path / "figure8.png").read_bytes()[:4] == b"\x89PNG"


def test_report_names_what_is_missing(tmp_path, capsys):
    (tmp_path / "report.json").write_text(json.dumps(dict(control=dict(sim="other", x=[], u=[]))))
    assert f8s.main(["report", "--out", str(tmp_path), "--no-plot"]) == 2
    assert "no control result for simulator 'arm0'" in capsys.readouterr().err
    assert f8s.main(["report", "--out", str(tmp_path / "nowhere")]) == 2
