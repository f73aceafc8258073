"""scenarios/gym-inverted-double-pendulum.toml (Gymnasium's InvertedDoublePendulum-v5, an unstable
plant) at a smoke budget from a scenario file outside the repository: the windows start in the
box around upright with inputs within U(±0.1), EDMD's dictionary degree is the one with the
lowest validation error of those it tried, and both models' closed loops are finite. The
classical yardstick (``koopbridge_experiments.gym_lqr``) is checked against closed forms."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

pytest.importorskip("gymnasium")
pytest.importorskip("mujoco")

from conftest import run_shipped_scenario  # noqa: E402

SMOKE = {"train_windows": 256, "val_windows": 32, "test_windows": 32}
#: The training and control budgets cut with the data.
CUTS = [("iterations = 3000, validate_every = 500", "iterations = 200, validate_every = 100"), ("steps = 200", "steps = 60")]


def test_double_pendulum_scenario_runs_at_a_smoke_budget(tmp_path):
    shipped, out = run_shipped_scenario(tmp_path, "gym-inverted-double-pendulum", SMOKE, CUTS)

    collect = tomllib.loads(shipped)["collect"]
    centre, radius = np.array(collect["x0_center"]), np.array(collect["x0_radius"])
    with np.load(out / "data" / "cart" / "train.npz") as d:
        x, u = d["x"], d["u"]
    assert x.shape == (SMOKE["train_windows"], collect["steps"] + 1, 6)
    assert np.all(np.abs(x[:, 0, :] - centre) <= radius + 1e-12)
    assert np.all(np.abs(u) <= 0.1 + 1e-12) and np.ptp(u) > 0.1

    # EDMD's degree: the lowest validation error among the degrees tried, each of them listed.
    metrics = json.loads((out / "models" / "gym-inverted-double-pendulum-cart-edmd" / "metrics.json").read_text())
    sel = metrics["degree_selection"]
    assert sel["by_validation"] and [t["degree"] for t in sel["trials"]] == list(range(1, len(sel["trials"]) + 1))
    scored = [(t["validation_error"], t["degree"]) for t in sel["trials"] if t["validation_error"] is not None]
    assert sel["chosen"] == min(scored)[1]
    assert metrics["config"]["degree"] == sel["chosen"]

    report = json.loads((out / "report.json").read_text())
    assert {c["model"] for c in report["controls"]} == {"gym-inverted-double-pendulum-cart-edmd", "gym-inverted-double-pendulum-cart"}
    for c in report["controls"]:
        xs, us = np.array(c["x"]), np.array(c["u"])
        assert xs.shape == (61, 6) and np.all(np.isfinite(xs)) and np.all(np.abs(us) <= 1.0 + 1e-12)


def test_lqr_yardstick_matches_closed_forms():
    from koopbridge.adapters.gym.sim import GymSimulator
    from koopbridge_experiments.gym_lqr import dlqr, linearise

    # dlqr on a scalar system: the Riccati fixed point p = q + a²p − (abp)²/(r + b²p) in closed form.
    a, b, q, r = 1.3, 0.5, 2.0, 0.7
    k = dlqr(np.array([[a]]), np.array([[b]]), np.array([[q]]), np.array([[r]]))
    # b²p² + (r(1 − a²) − q b²)p − qr = 0
    c1, c0 = r * (1 - a * a) - q * b * b, -q * r
    p = (-c1 + np.sqrt(c1 * c1 - 4 * b * b * c0)) / (2 * b * b)
    assert k[0, 0] == pytest.approx(a * b * p / (r + b * b * p), rel=1e-9)
    assert abs(a - b * k[0, 0]) < 1.0

    # linearise: a small step from upright matches A δx + B δu to second order.
    sim = GymSimulator("InvertedDoublePendulum-v5")
    try:
        am, bm = linearise(sim, np.zeros(6), np.zeros(1))
        dx, du = np.array([0.0, 1e-3, -1e-3, 0.0, 2e-3, 0.0]), np.array([1e-3])
        sim.reset(x0=dx)
        got = np.asarray(sim.step(du))
        assert np.allclose(got, am @ dx + bm @ du, atol=1e-6)
        assert np.max(np.abs(np.linalg.eigvals(am))) > 1.2  # the upright is unstable
        # LQR on it stabilises the model (every closed-loop eigenvalue inside the unit circle).
        kk = dlqr(am, bm, np.diag([1.0, 10, 10, 0.1, 0.1, 0.1]), np.eye(1))
        assert np.max(np.abs(np.linalg.eigvals(am - bm @ kk))) < 1.0
    finally:
        sim.close()
