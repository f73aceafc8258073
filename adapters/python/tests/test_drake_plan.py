"""The two-pass Gen3 trajectory optimisation with real Drake: the plan meets every constraint of
SPEC when checked on its samples (not trusted from the solver), the collision pass moves a path
that the first pass drives through the table, bad input and infeasible goals are typed errors."""

from __future__ import annotations

import numpy as np
import pytest

from koopbridge import InvalidInput
from koopbridge.adapters.drake.model import CONTINUOUS, POSITION_LIMITS, VELOCITY_LIMITS
from koopbridge.adapters.drake.plan import DimensionError, Gen3Planner, Infeasible, random_goals


@pytest.fixture(scope="module")
def planner():
    return Gen3Planner()


def _check_plan(planner, plan, start, goal, dt=0.001):
    t, q, qd = plan.sample(dt)
    assert 0.5 - 1e-6 <= plan.duration <= 5.0 + 1e-6
    assert t[0] == 0.0 and t[-1] == pytest.approx(plan.duration) and np.all(np.diff(t) > 0)
    np.testing.assert_allclose(q[0], start, atol=1e-6)
    np.testing.assert_allclose(q[-1], goal, atol=1e-6)
    np.testing.assert_allclose(qd[0], 0, atol=1e-6)
    np.testing.assert_allclose(qd[-1], 0, atol=1e-6)
    assert np.all(np.abs(qd) <= VELOCITY_LIMITS * (1 + 1e-6) + 1e-6)
    assert np.all(np.abs(q) <= POSITION_LIMITS + 1e-6)
    # The velocities are the derivative of the positions (trapezoid rule on the samples).
    np.testing.assert_allclose(np.diff(q, axis=0), 0.5 * (qd[1:] + qd[:-1]) * np.diff(t)[:, None], atol=1e-6)
    return t, q, qd


def test_two_pass_plan_meets_the_constraints(planner):
    start = np.zeros(7)
    goal = np.array([1.0, 0.6, -0.5, 1.2, 0.3, -0.8, 0.4])
    plan = planner.plan(start, goal)
    assert [p.name for p in plan.passes] == ["kinematic", "collision"]
    assert all(p.solver in ("snopt", "ipopt") and p.solve_time_s > 0 for p in plan.passes)
    _, q, _ = _check_plan(planner, plan, start, goal)
    assert min(planner.min_distance(qi) for qi in q[::20]) >= 0.0
    # Cost = duration + path length: the straight-line path length is a lower bound.
    assert plan.passes[0].cost >= plan.duration + np.linalg.norm(goal - start) - 1e-6


def test_collision_pass_moves_a_path_through_the_table(planner):
    # Two collision-free configurations (found by search) whose first-pass path drives the arm
    # 7 cm deep into the table or itself; the collision pass must go around.
    start = np.array([-1.63, 1.8, -1.68, 2.4, -1.12, 1.46, -2.41])
    goal = np.array([-0.81, 1.61, -0.27, 0.21, 2.07, -2.07, -1.32])
    assert planner.min_distance(start) > 0.01 and planner.min_distance(goal) > 0.01
    first = planner.plan(start, goal, collision=False)
    _, q1, _ = first.sample(0.01)
    both = planner.plan(start, goal)
    _, q2, _ = _check_plan(planner, both, start, goal, dt=0.01)
    d1 = min(planner.min_distance(q) for q in q1)
    d2 = min(planner.min_distance(q) for q in q2)
    assert d1 < -0.03 and d2 > 0.0, (d1, d2)


def test_goal_in_collision_is_infeasible_naming_the_pass(planner):
    goal = np.array([0.0, 2.3, 0.0, 0.0, 0.0, 0.0, 0.0])  # the arm laid into the table
    assert planner.min_distance(goal) < 0
    with pytest.raises(Infeasible) as e:
        planner.plan(np.zeros(7), goal)
    assert e.value.pass_name == "collision" and e.value.code == "infeasible"
    assert "pass 'collision'" in str(e.value) and "goal configuration" in str(e.value)


def test_bad_configurations_are_typed_errors(planner):
    with pytest.raises(DimensionError, match="goal has 6 values, the Gen3 has 7"):
        planner.plan(np.zeros(7), np.zeros(6))
    with pytest.raises(InvalidInput, match="start has non-finite values"):
        planner.plan([np.nan] + [0.0] * 6, np.zeros(7))
    with pytest.raises(InvalidInput, match=r"goal: joint 2 at 3\.0000 rad is outside its limits \[-2\.4100, 2\.4100\]"):
        planner.plan(np.zeros(7), [0, 3.0, 0, 0, 0, 0, 0])
    plan = planner.plan(np.zeros(7), np.full(7, 0.1), collision=False)
    for dt in (0.0, -1.0, float("nan")):
        with pytest.raises(InvalidInput, match="dt must be"):
            plan.sample(dt)


def test_random_goals_uniform_within_limits_and_reproducible(planner):
    g = random_goals(5, 4000)
    np.testing.assert_array_equal(g, random_goals(5, 4000))
    assert not np.array_equal(g, random_goals(6, 4000))
    hi = np.where(CONTINUOUS, np.pi, POSITION_LIMITS)
    assert np.all(np.abs(g) <= hi)
    # Uniform: each joint's quartiles near -hi/2, 0, hi/2 (4000 draws: standard error ~1.4%).
    np.testing.assert_allclose(np.quantile(g, [0.25, 0.5, 0.75], axis=0) / hi, np.array([[-0.5], [0.0], [0.5]]).repeat(7, 1), atol=0.06)
    free = random_goals(5, 20, planner=planner, margin=0.01)
    assert all(planner.min_distance(q) >= 0.01 for q in free)


def test_the_ipopt_fallback_stops_at_its_iteration_limit():
    """Goal 108 of seed 1 from goal 107 has no collision-free trajectory: SNOPT gives up and
    IPOPT, the fallback, ran to its default 3000 iterations (39 s) before the limit was set. With
    the limit it stops there, says so, and a bad limit is refused."""
    p = Gen3Planner(ipopt_max_iterations=20)
    goals = random_goals(1, 109, planner=p, margin=0.02)
    with pytest.raises(Infeasible) as e:
        p.plan(goals[107], goals[108])
    assert "ipopt: kIterationLimit" in str(e.value), str(e.value)
    with pytest.raises(InvalidInput):
        Gen3Planner(ipopt_max_iterations=0)
