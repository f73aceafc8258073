"""The Kinova steps of scenarios/kinova-drake.toml: held-out goals come from no collection
session, the reference chains real Drake plans (the planner service's own handler) and skips an
infeasible goal, and the lifted-LQR gain solves the Riccati equation (closed form in 1-D,
residual in n-D)."""

from __future__ import annotations

import numpy as np
import pytest

from koopbridge.adapters.drake.collect import goal_seed
from koopbridge.adapters.drake.plan import Gen3Planner, Infeasible
from koopbridge.adapters.drake.planner import handler
from koopbridge_experiments import kinova_scenario as ks


@pytest.fixture(scope="module")
def planner():
    return Gen3Planner()


def test_held_out_goal_seeds_are_no_collection_sessions_seeds(planner):
    goals = ks.held_out_goals(42, 2, planner)
    used = {goal_seed(42, split, s) for split in ("train", "val", "test") for s in range(100)}
    assert all(s not in used for s, _ in goals)
    assert all(planner.min_distance(g) >= 0.02 for _, g in goals)


def test_reference_chains_plans_and_skips_infeasible_goals(planner):
    plan = handler(planner)

    def ask(start, goal, dt):
        try:
            return plan(start, goal, dt)
        except Infeasible as e:
            assert e.code == "infeasible"
            raise

    g1 = np.array([0.5, 0.4, 0.0, 0.8, 0.0, 0.5, 0.0])
    bad = np.array([0.0, 2.3, 0, 0, 0, 0, 0])  # lies in the table
    g2 = np.array([-0.3, 0.2, 0.3, 0.5, -0.4, 0.2, 0.6])
    ref = ks.plan_reference(ask, [(1, g1), (2, bad), (3, g2)], 0.001, 0.05, np.zeros(7))
    x, ff, plans = ref["x"], ref["ff"], ref["plans"]
    assert "error" in plans[1] and "error" not in plans[0] and "error" not in plans[2]
    assert x.shape[1] == 14 and len(ff) == len(x) - 1
    np.testing.assert_array_equal(x[0], np.zeros(14))
    n1 = plans[0]["steps"]
    np.testing.assert_allclose(x[n1, :7], g1, atol=1e-6)  # plan 1 ends at its goal ...
    np.testing.assert_allclose(x[n1 + 50, :7], g1, atol=1e-6)  # ... held 50 ms at rest
    assert np.all(x[n1 + 1 : n1 + 51, 7:] == 0) and np.all(ff[n1 : n1 + 50] == 0)
    assert plans[2]["start"] == pytest.approx(g1.tolist(), abs=1e-6)  # plan 2 starts there
    np.testing.assert_allclose(x[-1, :7], g2, atol=1e-6)
    # The feed-forward at step k is the planned velocity at k: integrating it follows q.
    np.testing.assert_allclose(x[0, :7] + 0.001 * np.cumsum(ff[:n1], axis=0)[-1], g1, atol=2e-2)


def test_tracking_errors_written_out():
    ref = np.zeros((4, 14))
    x = np.zeros((3, 14))
    x[:, 0] = [0.0, 0.3, -0.4]
    e = ks.tracking_errors(x, ref)
    assert e["rms_rad"] == pytest.approx(np.sqrt((0.09 + 0.16) / 21))
    assert e["final_rad"] == pytest.approx(0.4) and e["rms_per_joint_rad"][0] == pytest.approx(np.sqrt(0.25 / 3), abs=1e-6)


def test_report_scores_the_engines_rows_and_the_arm_held_still(tmp_path, planner, capsys):
    """Rows that are the feed-forward run itself (nominal, and on an arm realising half of each
    command, labelled ``…-mismatch`` with that perturbation) score exactly as the tracking error
    written out here; the LQR row's settings are reported; the report adds the arm held still and
    kinova.png; rows on the mismatched arm without one shared command gain are refused."""
    import json

    from koopbridge.adapters.drake.sim import DrakeGen3Sim

    ref = ks.plan_reference(handler(planner), [(1, np.array([0.3, 0.2, 0.0, 0.4, 0.0, 0.3, 0.0]))], 0.001, 0.05, np.zeros(7))
    np.save(tmp_path / ks.REFERENCE, ref["x"])
    np.save(tmp_path / ks.FEEDFORWARD, ref["ff"])

    def feedforward_run(gain: float) -> np.ndarray:
        sim = DrakeGen3Sim(command_gain=gain)
        return np.array([sim.reset(x0=ref["x"][0])] + [sim.step(u) for u in ref["ff"]])

    xs, slow = feedforward_run(1.0), feedforward_run(0.5)

    def row(label: str, x: np.ndarray, gain: float | None = None, mpc: dict | None = None) -> dict:
        return dict(sim="gen3", model="kinova-gen3", label=label, dt=0.001, x=x.tolist(), u=ref["ff"].tolist(), solve_median_us=1.0,
                    perturbation=None if gain is None else {"command_gain": gain}, mpc=mpc)

    lqr = dict(law="lqr", q=[1.0] * 14, r=[0.001] * 7)
    rows = [row("koopman-mpc", xs), row("feed-forward", xs), row("feed-forward-lqr", xs, mpc=lqr), row("feed-forward-mismatch", slow, 0.5),
            dict(sim="other", x=[], u=[])]
    (tmp_path / "report.json").write_text(json.dumps(dict(control=rows[0], controls=rows)))
    assert ks.main(["report", "--out", str(tmp_path)]) == 0
    rep = json.loads((tmp_path / "report.json").read_text())["kinova"]
    c = rep["controllers"]
    assert set(c) == {"koopman-mpc", "feed-forward", "feed-forward-lqr"} and rep["through_service"] == "koopman-mpc"
    assert rep["lqr"]["q"] == lqr["q"] and rep["lqr"]["r"] == lqr["r"]
    for got, x in ((c["feed-forward"], xs), (rep["disturbed"]["controllers"]["feed-forward"], slow)):
        err = x[:, :7] - ref["x"][:, :7]
        assert got["rms_rad"] == pytest.approx(np.sqrt(np.mean(err**2)), rel=1e-12)
    assert rep["disturbed"]["command_gain"] == 0.5 and set(rep["disturbed"]["controllers"]) == {"feed-forward"}
    assert rep["steps"] == len(ref["ff"])
    held = ref["x"][:, :7] - ref["x"][0, :7]
    assert rep["hold_still"]["rms_rad"] == pytest.approx(np.sqrt(np.mean(held**2)), rel=1e-12)
    assert rep["hold_still"]["final_rad"] == pytest.approx(np.max(np.abs(held[-1])), rel=1e-12) and rep["hold_still"]["final_rad"] > 0.1
    assert (tmp_path / "kinova.png").read_bytes()[:4] == b"\x89PNG"
    rows[3]["perturbation"] = None
    (tmp_path / "report.json").write_text(json.dumps(dict(controls=rows)))
    assert ks.main(["report", "--out", str(tmp_path), "--no-plot"]) == 2
    assert "command_gain" in capsys.readouterr().err
