"""The Van der Pol FMU (an autonomous system: no inputs) is valid per fmpy, the FMU adapter serves
it with nu = 0, and its outputs match an independent fine-step RK4 in numpy and fmpy's own
simulate_fmu."""

from __future__ import annotations

import numpy as np
import pytest
from fmpy import simulate_fmu
from fmpy.validation import validate_fmu

from conftest import _fmu
from koopbridge.adapters.fmu.sim import FmuSimulator, InvalidInput


@pytest.fixture(scope="session")
def vdp_fmu():
    return _fmu("van_der_pol")


def vdp(path, **kw):
    return FmuSimulator(str(path), [], ["x0", "x1"], dt=0.05, initial=["x0_start", "x1_start"], **kw)


def reference(x, mu, t_total, h=1e-4):
    """Van der Pol integrated with classical RK4 at a fixed step h (written here, independently of
    the FMU's C code)."""

    def f(y):
        return np.array([y[1], mu * (1.0 - y[0] ** 2) * y[1] - y[0]])

    y = np.asarray(x, float).copy()
    n = int(round(t_total / h))
    for _ in range(n):
        k1 = f(y)
        k2 = f(y + 0.5 * h * k1)
        k3 = f(y + 0.5 * h * k2)
        k4 = f(y + h * k3)
        y = y + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return y


def test_fmpy_validate_finds_no_problem(vdp_fmu):
    assert validate_fmu(str(vdp_fmu)) == []


def test_info_has_no_inputs(vdp_fmu):
    d = vdp(vdp_fmu).info()
    assert d["state_names"] == ["x0", "x1"] and d["input_names"] == []
    assert d["fmu"]["fmi_version"] == "2.0"
    starts = {v["name"]: v["start"] for v in d["fmu"]["variables"]}
    assert float(starts["mu"]) == 1.0 and float(starts["max_substep"]) == 0.001


@pytest.mark.parametrize("mu", [1.0, 2.5])
def test_trajectory_matches_a_fine_step_rk4(vdp_fmu, mu):
    sim = vdp(vdp_fmu, parameters={"mu": mu})
    rng = np.random.default_rng(5)
    for _ in range(3):
        x0 = rng.uniform([-2.5, -3.0], [2.5, 3.0])
        x = sim.reset(x0=x0)
        np.testing.assert_array_equal(x, x0)
        want = np.asarray(x0, float)
        worst = 0.0
        for _ in range(40):  # 2 s in 50 ms communication steps
            x = sim.step([])
            want = reference(want, mu, 0.05)
            worst = max(worst, float(np.max(np.abs(x - want))))
        # RK4 with 1 ms substeps against RK4 with 0.1 ms: global error O(1e-12 .. 1e-10).
        assert worst < 1e-8, (mu, x0, worst)
    # The dynamics are not trivial: mu changes them (over 2 s from (2, 0)).
    assert np.max(np.abs(reference([2.0, 0.0], mu, 2.0) - reference([2.0, 0.0], 0.2, 2.0))) > 0.1


def test_matches_fmpys_simulate_fmu(vdp_fmu):
    """fmpy's own co-simulation loop (its defaults: start (2, 0), mu = 1) with 0.1 ms substeps
    against the adapter's steps with the default 1 ms."""
    res = simulate_fmu(str(vdp_fmu), stop_time=4.0, output_interval=0.05, start_values={"max_substep": 1e-4})
    sim = vdp(vdp_fmu)
    x = sim.reset(x0=[2.0, 0.0])
    xs = [x]
    for _ in range(len(res) - 1):
        xs.append(sim.step(np.zeros(0)))
    got = np.array(xs)
    want = np.column_stack([res["x0"], res["x1"]])
    assert np.max(np.abs(got - want)) < 1e-8
    # ... and the limit cycle is reached: x0 swings to about -2 (amplitude ~2 at mu = 1).
    assert want[:, 0].min() < -1.9


def test_an_input_is_refused(vdp_fmu):
    sim = vdp(vdp_fmu)
    sim.reset(x0=[1.0, 0.0])
    with pytest.raises(InvalidInput, match="0 values"):
        sim.step([0.5])
    x = sim.step([])  # still serving
    np.testing.assert_allclose(x, reference([1.0, 0.0], 1.0, 0.05), atol=1e-9)


def test_seeded_reset_draws_within_the_range(vdp_fmu):
    sim = vdp(vdp_fmu, x0_low=[-2.0, -1.0], x0_high=[2.0, 1.0])
    xs = np.array([sim.reset(seed=s) for s in range(20)])
    assert np.all(xs >= [-2.0, -1.0]) and np.all(xs <= [2.0, 1.0])
    assert len({tuple(x) for x in xs}) == 20
