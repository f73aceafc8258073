"""The figure-8 steps of scenarios/franka-figure8.toml: the reference file is the task's
full-state reference and the plan file its velocities, the scenario's x0 is the task's start, and
the report step scores every closed loop of report.json with SPEC's error, written out
independently, for trajectories whose error is known."""

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
    np.testing.assert_allclose(sc["control_defaults"]["x0"], want, atol=1e-9)
    (sim,) = sc["sims"]
    assert sim["command"][sim["command"].index("--u-limit") + 1] == "1.0"
    assert all("--u-limit 1.0" in h["command"] for h in sc["hooks"])
    rows = {c["label"]: c for c in sc["control"]}
    assert len(rows["koopman-mpc"]["mpc"]["q"]) == 17
    # The joint follower's position loop is the greedy follower's gain 1/dt.
    dt = f8s.simulator(u_limit=U_LIMIT).options.dt
    assert rows["joint-follower"]["position_loop"]["gain"] == pytest.approx(1.0 / dt)


def test_the_plan_is_the_references_velocities_and_its_feedforward_ends_at_rest(tmp_path):
    ref, plan, ff = (tmp_path / f"{n}.npy" for n in ("ref", "plan", "ff"))
    args = ["reference", "--u-limit", "1.0", "--steps", "130", "--out", str(ref)]
    assert f8s.main([*args, "--plan", str(plan), "--feedforward", str(ff), "--horizon", "15"]) == 0
    r, p, u = np.load(ref), np.load(plan), np.load(ff)
    assert p.shape == (130, 17) and u.shape == (129 + 15, 7)
    dt = f8s.simulator(u_limit=U_LIMIT).options.dt
    np.testing.assert_allclose(u[:129], (r[1:, 3:10] - r[:-1, 3:10]) / dt, rtol=1e-12)  # under the clip here
    assert np.all(u[129:] == 0)
    np.testing.assert_array_equal(p[:, :10], r[:, :10])
    np.testing.assert_allclose(p[1:, 10:], u[:129], rtol=1e-12)
    assert f8s.main([*args, "--plan", str(plan)]) == 2  # the two go together


def _follow(sim, task, x0, steps: int, gain: float) -> tuple[np.ndarray, np.ndarray]:
    """The greedy joint follower with ``gain`` (0: zero input), written out here."""
    x = sim.reset(x0=x0)
    xs, us = [x], []
    for k in range(steps - 1):
        u = joint_p_command(x[3:10], task.q[k + 1], gain, U_LIMIT)
        x = sim.step(u)
        xs.append(x)
        us.append(u)
    return np.array(xs), np.array(us)


@pytest.mark.parametrize("as_list", [False, True])
def test_report_scores_every_closed_loop_with_specs_error(tmp_path, as_list):
    steps = 160
    sim = f8s.simulator(u_limit=U_LIMIT)
    task = references(sim, steps)
    loops = {"koopman-mpc": _follow(sim, task, task.x0, steps, 50.0), "zero-input": _follow(sim, task, task.x0, steps, 0.0)}
    entries = [dict(sim="arm0", model="m", label=None if name == "koopman-mpc" else name, x=x.tolist(), u=u.tolist())
               for name, (x, u) in loops.items()]
    entries.append(dict(sim="other", model="m", x=[], u=[]))  # another simulator's: not scored
    body = dict(name="t", controls=entries) if as_list else dict(name="t", control=entries[0])
    (tmp_path / "report.json").write_text(json.dumps(body))
    assert f8s.main(["report", "--u-limit", "1.0", "--out", str(tmp_path)]) == 0
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["name"] == "t"  # the orchestrator's report is kept
    e = rep["figure8"]["errors"]
    assert set(e) == (set(loops) if as_list else {"koopman-mpc"})
    for name in e:
        xs = loops[name][0]
        want = np.sqrt(sum((xs[k, 1] - task.targets[k, 1]) ** 2 + (xs[k, 2] - task.targets[k, 2]) ** 2 for k in range(100, steps)))
        assert e[name] == pytest.approx(want, rel=1e-9), name
    if as_list:
        assert e["zero-input"] > 5 * e["koopman-mpc"]
    assert (tmp_path / "figure8.png").read_bytes()[:4] == b"\x89PNG"


def test_report_names_what_is_missing(tmp_path, capsys):
    (tmp_path / "report.json").write_text(json.dumps(dict(control=dict(sim="other", x=[], u=[]))))
    assert f8s.main(["report", "--out", str(tmp_path), "--no-plot"]) == 2
    assert "no control result for simulator 'arm0'" in capsys.readouterr().err
    assert f8s.main(["report", "--out", str(tmp_path / "nowhere")]) == 2
