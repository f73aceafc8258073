"""The project's own FMUs: valid per fmpy, and their dynamics match the Rust reference systems
(koopman::systems, an adaptive DOPRI5 integrator) to within the integrators' tolerance."""

from __future__ import annotations

import numpy as np
import pytest
from fmpy.validation import validate_fmu

import koopbridge
from koopbridge.adapters.fmu.sim import FmuSimulator


@pytest.mark.parametrize("name", ["damped_fmu", "double_fmu"])
def test_fmpy_validate_finds_no_problem(name, request):
    path = request.getfixturevalue(name)
    assert validate_fmu(str(path)) == []


def damped(path, **kw):
    return FmuSimulator(str(path), ["u"], ["theta", "omega"], dt=0.02, initial=["theta0", "omega0"], **kw)


def double(path, **kw):
    return FmuSimulator(
        str(path),
        ["u1", "u2"],
        ["theta1", "theta2", "omega1", "omega2"],
        dt=0.01,
        initial=["theta1_0", "theta2_0", "omega1_0", "omega2_0"],
        **kw,
    )


def test_info_reports_the_fmus_own_description(damped_fmu, double_fmu):
    d = damped(damped_fmu).info()
    assert d["fmu"]["fmi_version"] == "2.0"
    assert d["state_names"] == ["theta", "omega"] and d["input_names"] == ["u"]
    assert d["fmu"]["units"] == {"inputs": ["N"], "outputs": ["rad", "rad/s"]}
    starts = {v["name"]: v["start"] for v in d["fmu"]["variables"]}
    assert float(starts["g"]) == 9.8 and float(starts["max_substep"]) == 0.001
    q = double(double_fmu).info()
    assert q["fmu"]["fmi_version"] == "3.0"
    assert q["fmu"]["units"]["outputs"] == ["rad", "rad", "rad/s", "rad/s"]


def one_step_errors(sim, ref, rng, x0_low, x0_high, u_bound, steps):
    """Largest one-step difference FMU vs reference, each step started from the FMU's state."""
    worst = 0.0
    x = sim.reset(x0=rng.uniform(x0_low, x0_high))
    for _ in range(steps):
        u = rng.uniform(-u_bound, u_bound, size=len(sim.inputs))
        want = ref.step(x, u)
        x = sim.step(u)
        worst = max(worst, float(np.max(np.abs(x - want))))
    return worst


def test_damped_pendulum_fmu_matches_the_rust_reference(damped_fmu):
    sim, ref = damped(damped_fmu), koopbridge.ReferenceSystem("damped-pendulum")
    rng = np.random.default_rng(1)
    worst = max(one_step_errors(sim, ref, rng, [-2 * np.pi, -8], [2 * np.pi, 8], 8.0, 50) for _ in range(4))
    # RK4 with 1 ms substeps against DOPRI5: both far below 1e-6 per 20 ms step.
    assert worst < 1e-7, worst
    # A whole trajectory too (the damped pendulum is not chaotic): same inputs, open loop.
    x_ref = x_fmu = sim.reset(x0=[-2.5, 0.1])
    for k in range(100):
        u = [8.0 * np.sin(0.1 * k)]
        x_ref = ref.step(x_ref, u)
        x_fmu = sim.step(u)
    assert np.max(np.abs(x_fmu - x_ref)) < 1e-6


def test_double_pendulum_fmu_matches_the_rust_reference(double_fmu):
    sim, ref = double(double_fmu), koopbridge.ReferenceSystem("double-pendulum")
    rng = np.random.default_rng(2)
    lo = [-0.1 * np.pi, -0.1 * np.pi, -1, -1]
    worst = max(one_step_errors(sim, ref, rng, lo, np.negative(lo), 6.0, 50) for _ in range(4))
    assert worst < 1e-7, worst


def test_reference_comparison_would_catch_a_wrong_parameter(damped_fmu):
    # The same check with g = 9.81 instead of 9.8 must fail: the tolerance is not vacuous.
    sim, ref = damped(damped_fmu, parameters={"g": 9.81}), koopbridge.ReferenceSystem("damped-pendulum")
    worst = one_step_errors(sim, ref, np.random.default_rng(3), [-3, -3], [3, 3], 8.0, 20)
    assert worst > 1e-6


def test_rk4_substeps_converge(damped_fmu, double_fmu):
    # The integrator's own error: 1 ms substeps against 0.25 ms substeps over 1 s of motion.
    for make, nx, nu in ((damped, 2, 1), (double, 4, 2)):
        path = damped_fmu if make is damped else double_fmu
        coarse, fine = make(path), make(path, parameters={"max_substep": 2.5e-4})
        x0 = np.linspace(0.2, -0.3, nx)
        a, b = coarse.reset(x0=x0), fine.reset(x0=x0)
        for k in range(int(round(1.0 / coarse.dt))):
            u = np.full(nu, np.cos(0.3 * k))
            a, b = coarse.step(u), fine.step(u)
        assert 0 < np.max(np.abs(a - b)) < 1e-9


def test_reset_restarts_the_same_trajectory(damped_fmu):
    sim = damped(damped_fmu, x0_low=[-1, -1], x0_high=[1, 1])
    first = [sim.reset(seed=7)] + [sim.step([0.5]) for _ in range(10)]
    again = [sim.reset(seed=7)] + [sim.step([0.5]) for _ in range(10)]
    np.testing.assert_array_equal(np.array(first), np.array(again))
    other = sim.reset(seed=8)
    assert not np.array_equal(other, first[0])
    assert np.all(np.abs(first[0]) <= 1)
    default = sim.reset()
    np.testing.assert_array_equal(default, [0.0, 0.0])
