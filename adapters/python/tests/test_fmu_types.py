"""Every numeric FMI type through the FMU adapter (FmuSimulator, real fmpy, the test FMUs
typed_fmi2/typed_fmi3 of adapters/fmu/src): round trips through reset/step against the FMUs'
closed form, FMI 3 arrays as components with a structural size, values that cannot be
represented refused naming the variable (the FMU serving on), unservable variables refused at
start-up."""

from __future__ import annotations

import re
import zipfile

import numpy as np
import pytest
from fmpy import simulate_fmu
from fmpy.validation import validate_fmu

from conftest import _fmu
from koopbridge import InvalidInput
from koopbridge.adapters.fmu.sim import FmuError, FmuSimulator

IN3 = ["drive", "on", "mode", "gain", "i8", "u8", "i16", "u16", "u32", "i64", "u64"]
ECHO3 = ["i8_out", "u8_out", "i16_out", "u16_out", "i32_out", "u32_out", "i64_out", "u64_out"]
OUT3 = ["x", "steps", "xf", *ECHO3, "on_out", "mode_out", "y", "M"]
SIGN = {1: 1.0, 2: -1.0, 3: 0.0}


@pytest.fixture(scope="session")
def typed3():
    return _fmu("typed_fmi3")


@pytest.fixture(scope="session")
def typed2():
    return _fmu("typed_fmi2")


@pytest.mark.parametrize("name", ["typed_fmi2", "typed_fmi3"])
def test_fmpy_validate_finds_no_problem(name):
    assert validate_fmu(str(_fmu(name))) == []


def random_inputs3(rng: np.random.Generator) -> list[float]:
    """One input vector of typed_fmi3 (IN3 order), every value representable, extremes included."""
    return [
        float(rng.integers(-1000, 1001)),
        float(rng.integers(0, 2)),
        float(rng.integers(1, 4)),
        float(np.float32(rng.uniform(0, 10))),
        float(rng.choice([-128, 127, rng.integers(-128, 128)])),
        float(rng.integers(0, 201)),
        float(rng.choice([-32768, 32767, rng.integers(-32768, 32768)])),
        float(rng.choice([0, 65535, rng.integers(0, 65536)])),
        float(rng.choice([0, 2**32 - 1, rng.integers(0, 2**32)])),
        float(rng.choice([-(2**62), 2**53, rng.integers(-(2**40), 2**40)])),
        float(rng.choice([0, 2**63, rng.integers(0, 2**53)])),
    ]


def expected3(x: float, k: int, u: list[float], n: int) -> np.ndarray:
    """typed_fmi3's outputs (OUT3 order, y of size n) after k steps at state x with inputs u."""
    drive, on, mode, _, i8, u8, i16, u16, u32, i64, u64 = u
    echoes = [i8, u8, i16, u16, drive, u32, i64, u64]
    y = [(i + 1) * x for i in range(n)]
    M = [x + 10 * i + j for i in range(2) for j in range(2)]
    return np.array([x, k % 256, float(np.float32(x)), *echoes, on, mode, *y, *M])


def test_fmi3_every_type_round_trips_against_the_closed_form(typed3):
    n, dt = 5, 0.1
    sim = FmuSimulator(str(typed3), IN3, OUT3, dt=dt, parameters={"n": n, "x0": 0.25})
    assert sim.inputs == IN3
    assert sim.outputs[-9:] == ["y[0]", "y[1]", "y[2]", "y[3]", "y[4]", "M[0,0]", "M[0,1]", "M[1,0]", "M[1,1]"]
    info = sim.info()
    assert info["u_min"][:6] == [-1000, 0, 1, 0, -128, 0] and info["u_max"][:6] == [1000, 1, 3, 10, 127, 200]
    assert info["fmu"]["types"]["inputs"][:4] == ["Int32", "Boolean", "Enumeration", "Float32"]
    assert {v["name"]: v.get("shape") for v in info["fmu"]["variables"]}["y"] == [n]
    rng = np.random.default_rng(5)
    for _ in range(2):  # the second pass runs after fmi3Reset
        start = [0.0, 0.0, 1.0, 1.0, 0, 0, 0, 0, 0, 0, 0]
        np.testing.assert_array_equal(sim.reset(), expected3(0.25, 0, start, n))
        x = 0.25
        for k in range(1, 301):  # past 255: the UInt8 counter wraps
            u = random_inputs3(rng)
            got = sim.step(u)
            if u[1]:
                x += dt * u[3] * u[0] * SIGN[int(u[2])]
            np.testing.assert_array_equal(got, expected3(x, k, u, n), err_msg=f"step {k}")


def test_fmi3_matches_fmpys_own_simulation(typed3):
    # The same FMU run by fmpy.simulate_fmu (its own master algorithm) with constant inputs
    # (n at its start value: fmpy sizes arrays from the start values).
    start = {"x0": 1.5, "drive": 7, "on": True, "mode": 2, "gain": 0.5}
    res = simulate_fmu(str(typed3), start_values=start, output=["x", "y", "steps"], stop_time=1.0, step_size=0.1, output_interval=0.1)
    sim = FmuSimulator(str(typed3), ["drive", "on", "mode", "gain"], ["x", "y", "steps"], dt=0.1, parameters={"x0": 1.5})
    sim.reset()
    ours = np.array([sim.step([7, 1, 2, 0.5]) for _ in range(10)])
    theirs = np.array([[r["x"], *r["y"], r["steps"]] for r in res[1:]])
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12)


def test_fmi2_integer_boolean_enumeration_and_a_tunable_parameter(typed2):
    dt = 0.1
    sim = FmuSimulator(str(typed2), ["drive", "on", "mode", "gain"], ["x", "steps", "mode_out", "on_out"], dt=dt, parameters={"x0": -2.0, "offset": 0.5})
    assert sim.info()["u_min"] == [-1000, 0, 1, -np.inf] and sim.info()["u_max"] == [1000, 1, 3, np.inf]
    np.testing.assert_array_equal(sim.reset(), [-1.5, 0, 1, 0])
    rng = np.random.default_rng(2)
    x = -1.5
    for k in range(1, 101):
        u = [float(rng.integers(-1000, 1001)), float(rng.integers(0, 2)), float(rng.integers(1, 4)), rng.normal()]
        if u[1]:
            x += dt * u[3] * u[0] * SIGN[int(u[2])]
        np.testing.assert_array_equal(sim.step(u), [x, k, u[2], u[1]])


def test_typed_initial_state_and_seeded_draws(typed2):
    # An Integer and a Boolean as initial-state variables: x0 values are checked the same way.
    sim = FmuSimulator(str(typed2), [], ["x", "x", "x"], initial=["x0", "drive", "on"], x0_low=[-1, -5, 0], x0_high=[1, 5, 1])
    sim.reset(x0=[0.5, 3, 1])
    with pytest.raises(InvalidInput, match=r"initial 'drive' \(Integer\) cannot take 0\.5: not an integer"):
        sim.reset(x0=[0.5, 0.5, 1])
    for seed in range(5):  # a seeded draw is rounded for the discrete variables, so it is accepted
        sim.reset(seed=seed)


@pytest.mark.parametrize(
    "u, name, value, why",
    [
        ([1.5, 1, 1, 1], "drive", "1.5", "not an integer"),
        ([1, 2, 1, 1], "on", "2.0", "a Boolean is 0 or 1"),
        ([1, 1, 4, 1], "mode", "4.0", "not one of the enumeration's values"),
        ([1, 1, 1, -1], "gain", "-1.0", r"outside 0\.0\.\.10\.0"),
        ([1, 1, 1, 1e39], "gain", "1e+39", "outside the Float32 range"),
        ([float("nan"), 1, 1, 1], "drive", "nan", "not a finite number"),
        ([1001, 1, 1, 1], "drive", "1001.0", r"outside -1000\.\.1000"),
    ],
)
def test_values_that_cannot_be_represented_are_refused_naming_the_variable(typed3, u, name, value, why):
    sim = FmuSimulator(str(typed3), ["drive", "on", "mode", "gain"], ["x", "steps"], dt=0.1)
    sim.reset()
    sim.step([2, 1, 1, 1])
    with pytest.raises(InvalidInput, match=rf"FMU 'typed_fmi3\.fmu': input '{name}' \(\w+\) cannot take {re.escape(value)}: {why}"):
        sim.step(u)
    # Nothing was set or stepped: the FMU serves on from where it was.
    np.testing.assert_allclose(sim.step([2, 1, 1, 1]), [0.4, 2], rtol=0, atol=1e-15)


@pytest.mark.parametrize(
    "inp, value, why",
    [
        ("u8", 300, r"outside 0\.\.200"),
        ("u8", 201, r"outside 0\.\.200"),
        ("i8", -129, r"outside -128\.\.127"),
        ("u64", -1, "outside 0"),
        ("u16", 65536, "outside 0..65535"),
    ],
)
def test_integer_ranges_of_type_and_variable(typed3, inp, value, why):
    sim = FmuSimulator(str(typed3), [inp], [f"{inp}_out"], dt=0.1)
    sim.reset()
    with pytest.raises(InvalidInput, match=rf"input '{inp}' \(\w+\) cannot take {float(value)!r}: {why}"):
        sim.step([value])
    np.testing.assert_array_equal(sim.step([1]), [1])  # and serves on


def test_array_elements_and_structural_size(typed3):
    sim = FmuSimulator(str(typed3), ["drive", "on"], ["y[1]", "M[1,0]", "y[6]"], dt=0.5, parameters={"n": 8, "x0": 1.0})
    np.testing.assert_array_equal(sim.reset(), [2.0, 11.0, 7.0])
    np.testing.assert_array_equal(sim.step([4, 1]), [6.0, 13.0, 21.0])
    assert FmuSimulator(str(typed3), [], ["y"]).outputs == ["y[0]", "y[1]", "y[2]"]  # the start size, 3
    # An array input: its elements are components too, set in one call (wsum = w[0] + 2 w[1]).
    sim = FmuSimulator(str(typed3), ["w", "drive"], ["wsum", "w[1]", "w[0]"], dt=0.1)
    assert sim.inputs == ["w[0]", "w[1]", "drive"] and sim.info()["fmu"]["start"]["inputs"] == [0.0, 0.0, 0]
    np.testing.assert_array_equal(sim.reset(), [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(sim.step([1.5, -2.25, 3]), [-3.0, -2.25, 1.5])


@pytest.mark.parametrize(
    "kw, msg",
    [
        (dict(outputs=["label"]), "variable 'label' is of type String, which cannot be served as a number"),
        (dict(inputs=["blob"]), "variable 'blob' is of type Binary"),
        (dict(inputs=["x"]), "'x' has causality 'output', it cannot be an input"),
        (dict(inputs=["y"]), r"'y\[0\]' has causality 'output', it cannot be an input"),
        (dict(inputs=["x0"]), "'x0' is a fixed parameter; it cannot be set while stepping"),
        (dict(inputs=["w[1]"]), r"input variable 'w' must be given whole and once \(FMI sets all 2 elements"),
        (dict(inputs=["w", "w[0]"]), "input variable 'w' must be given whole and once"),
        (dict(initial=["y[0]"], outputs=["x"]), r"'y\[0\]' .* cannot be set before initialisation"),
        (dict(outputs=["y[3]"]), r"'y\[3\]': index out of range for 'y' of shape \[3\]"),
        (dict(outputs=["M[1]"]), r"'M\[1\]': index out of range for 'M' of shape \[2, 2\]"),
        (dict(outputs=["x[0]"]), "variable 'x' is not an array"),
        (dict(parameters={"n": 9}), r"parameter 'n' \(UInt64\) cannot take 9\.0: outside 1\.\.8"),
        (dict(parameters={"n": 2.5}), r"the size of array 'y' is unknown|parameter 'n' \(UInt64\) cannot take 2\.5"),
        (dict(parameters={"steps": 1}), "'steps' .* cannot be set before initialisation, so it cannot be an parameter"),
        (dict(parameters={"drive": 0.5}), r"parameter 'drive' \(Int32\) cannot take 0\.5: not an integer"),
    ],
)
def test_unservable_variables_are_refused_at_start_up(typed3, kw, msg):
    args = dict(inputs=["drive"], outputs=["x", "y"]) | kw
    with pytest.raises(FmuError, match=msg):
        FmuSimulator(str(typed3), **args)


def test_fixed_fmi2_parameter_is_not_an_input_and_string_not_an_output(typed2):
    with pytest.raises(FmuError, match="'offset' is a fixed parameter; it cannot be set while stepping"):
        FmuSimulator(str(typed2), ["offset"], ["x"])
    with pytest.raises(FmuError, match="'label' is of type String"):
        FmuSimulator(str(typed2), ["drive"], ["x", "label"])
    with pytest.raises(FmuError, match=r"'drive\[0\]': variable 'drive' is not an array"):
        FmuSimulator(str(typed2), ["drive[0]"], ["x"])


def test_an_fmu_with_neither_interface_is_not_called_model_exchange_only(tmp_path, damped_fmu):
    bare = tmp_path / "bare.fmu"
    with zipfile.ZipFile(damped_fmu) as src, zipfile.ZipFile(bare, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "modelDescription.xml":
                data = re.sub(r"<CoSimulation\s[^>]*/>", "", data.decode()).encode()
            dst.writestr(item, data)
    with pytest.raises(FmuError, match=r"no co-simulation interface \(FMI 2\.0; neither co-simulation nor model exchange\)") as e:
        FmuSimulator(str(bare), ["u"], ["theta"])
    assert "model exchange only" not in str(e.value)


def test_a_clock_is_refused_at_start_up(tmp_path, typed3):
    # typed_fmi3 with a Clock input added to its model description (fmpy reads it as type Clock).
    clocked = tmp_path / "clocked.fmu"
    tick = '    <Clock name="tick" valueReference="40" causality="input" variability="discrete" intervalVariability="triggered"/>\n'
    with zipfile.ZipFile(typed3) as src, zipfile.ZipFile(clocked, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "modelDescription.xml":
                data = data.decode().replace("  </ModelVariables>", tick + "  </ModelVariables>").encode()
            dst.writestr(item, data)
    with pytest.raises(FmuError, match=r"FMU 'clocked\.fmu': variable 'tick' is of type Clock, which cannot be served as a number"):
        FmuSimulator(str(clocked), ["tick"], ["x"])
    assert FmuSimulator(str(clocked), ["drive"], ["x"]).outputs == ["x"]  # the rest is served
