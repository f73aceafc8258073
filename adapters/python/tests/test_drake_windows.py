"""Planned-trajectory windows of the Drake simulator (``collect`` with the planned policy):
the same seed gives the same bytes, a block collected alone equals the same windows of a longer
run (resumable), each window starts at a planned state and applies the planned velocities; the
policy travels over Zenoh (``collect`` request) and other simulators refuse it as unsupported."""

from __future__ import annotations

import numpy as np
import pytest

from koopbridge import InvalidInput, SimulatorAdapter, Unsupported
from koopbridge.adapters.drake.sim import DrakeGen3Sim
from koopbridge.adapters.drake.windows import PlannedPolicy, plan_for
from koopbridge.collect import PlannedPolicy as SdkPlannedPolicy
from koopbridge.collect import collect_windows, policy_from_json
from koopbridge.testing import listening_client


@pytest.fixture(scope="module")
def sim():
    return DrakeGen3Sim()


def test_planned_windows_are_deterministic_resumable_and_on_the_plan(sim):
    pol = {"kind": "planned", "windows_per_plan": 3}
    a = sim.collect(pol, 5, 5, 15)
    b = sim.collect(PlannedPolicy(3), 5, 5, 15)
    assert a.x.shape == (5, 16, 14) and a.u.shape == (5, 15, 7)
    assert a.x.tobytes() == b.x.tobytes() and a.u.tobytes() == b.u.tobytes()
    part = sim.collect(pol, 5, 2, 15, start=3)
    assert part.x.tobytes() == a.x[3:5].tobytes() and part.start == 3
    assert a.reset_seeds.tolist() == [0, 0, 0, 1, 1]
    # Window 0 of plan 0 starts at the plan's start at rest with its first planned velocities.
    plan, _ = plan_for(sim._planner, 5, 0)
    _, q, qd = plan.sample(sim.dt)
    np.testing.assert_allclose(a.x[0, 0], np.r_[q[0], qd[0]], atol=1e-12)
    np.testing.assert_allclose(a.u[0], qd[:15], atol=1e-12)
    # The last window of plan 0 ends at the goal.
    np.testing.assert_allclose(a.u[2][-1], qd[-2], atol=1e-12)
    # Another seed, other plans.
    assert not np.array_equal(sim.collect(pol, 6, 1, 15).x, a.x[:1])


def test_planned_policy_json_is_checked(sim):
    bads = ({"kind": "planned", "windows_per_plan": 0}, {"kind": "planned", "other": 1},
            {"kind": "planned", "dither": -0.1}, {"kind": "planned", "dither": "0.2"}, {"kind": "planned", "dither": float("nan")})
    for bad in bads:
        with pytest.raises(InvalidInput):
            sim.collect(bad, 1, 1, 15)
    assert PlannedPolicy.from_json(PlannedPolicy(4).to_json()) == PlannedPolicy(4)
    assert PlannedPolicy(4, 0.2).to_json() == {"kind": "planned", "windows_per_plan": 4, "dither": 0.2}
    assert PlannedPolicy.from_json(PlannedPolicy(4, 0.2).to_json()) == PlannedPolicy(4, 0.2)


def test_dither_excites_the_commands_off_the_plan_deterministically(sim):
    plain = sim.collect(PlannedPolicy(3), 5, 3, 15)
    a = sim.collect(PlannedPolicy(3, 0.2), 5, 3, 15)
    assert a.u.tobytes() == sim.collect({"kind": "planned", "windows_per_plan": 3, "dither": 0.2}, 5, 3, 15).u.tobytes()
    # Resumable: window 2 alone draws what it drew in the block.
    assert sim.collect(PlannedPolicy(3, 0.2), 5, 1, 15, start=2).u.tobytes() == a.u[2:3].tobytes()
    # The same windows (starts) as without the dither; commands within ±0.2 of the plan's and
    # within the limits; the excitation breaks the command/velocity collinearity.
    np.testing.assert_array_equal(a.x[:, 0], plain.x[:, 0])
    d = a.u - plain.u
    from koopbridge.adapters.drake.model import VELOCITY_LIMITS

    assert np.all(np.abs(d) <= 0.2 + 1e-12) and np.std(d) > 0.05
    assert np.all(np.abs(a.u) <= VELOCITY_LIMITS + 1e-12)
    qd, u = a.x[:, :-1, 7:].reshape(-1, 7), a.u.reshape(-1, 7)
    qd0, u0 = plain.x[:, :-1, 7:].reshape(-1, 7), plain.u.reshape(-1, 7)
    resid = lambda c, v: np.sqrt(np.mean((c - v) ** 2))  # noqa: E731
    assert resid(u, qd) > 3 * resid(u0, qd0), (resid(u, qd), resid(u0, qd0))  # 0.113 vs 0.024


def test_planned_policy_is_one_sdk_type_and_unsupported_without_a_planner(sim):
    assert PlannedPolicy is SdkPlannedPolicy
    assert policy_from_json({"kind": "planned"}) == PlannedPolicy(20)
    assert policy_from_json({"kind": "planned", "windows_per_plan": 7}).to_json() == {"kind": "planned", "windows_per_plan": 7}
    with pytest.raises(InvalidInput, match="planned"):
        policy_from_json({"kind": "sine"})
    # The generic per-window collection (what the FMU and MuJoCo adapters use) cannot plan.
    with pytest.raises(Unsupported):
        collect_windows(sim, PlannedPolicy(2), 1, 1, 15)


def test_the_drake_adapter_serves_the_planned_policy_over_zenoh(sim, session_id, serve_in_thread):
    local = sim.collect(PlannedPolicy(2), 11, 3, 15, start=2)
    client, ep = listening_client(session_id)
    with serve_in_thread(SimulatorAdapter(DrakeGen3Sim()), session=session_id, id="gen3", connect=[ep]) as s:
        with client as c:
            c.connect_sim("gen3", timeout=30)
            x, u = c.collect("gen3", seed=11, block=1, block_windows=2, windows=2, steps=15, policy={"kind": "planned", "windows_per_plan": 2})
            x1, _ = c.collect("gen3", seed=11, block=2, block_windows=2, windows=1, steps=15, policy={"kind": "planned", "windows_per_plan": 2})
    assert s.error is None
    assert x.tobytes() == local.x[:2].tobytes() and u.tobytes() == local.u[:2].tobytes()
    assert x1.tobytes() == local.x[2:3].tobytes()
    # Windows 2, 3 are plan 1, window 4 plan 2: each starts on its plan at a planned state.
    assert local.reset_seeds.tolist() == [1, 1, 2]
