"""The FMU adapter as a child process (`python -m koopbridge.adapters.fmu`), driven over Zenoh by
koopbridge.Client: data through the FMU matches the Rust reference system; errors are typed
replies naming the FMU; a killed adapter is reported by name within a second."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest

import koopbridge
from conftest import Child, fmu_adapter_cmd, free_endpoint


def test_help_and_describe(damped_fmu):
    out = subprocess.run([sys.executable, "-m", "koopbridge.adapters.fmu", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "--outputs" in out.stdout and "--free-run" in out.stdout
    out = subprocess.run(fmu_adapter_cmd(damped_fmu, "x", "y") + ["--describe"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout)
    assert info["kind"] == "fmu" and info["fmu"]["fmi_version"] == "2.0" and info["u_max"] == [8.0]


def test_bad_command_lines_fail_clearly(tmp_path, damped_fmu):
    out = subprocess.run(
        [sys.executable, "-m", "koopbridge.adapters.fmu", str(tmp_path / "x.fmu"), "--outputs", "a"], capture_output=True, text=True
    )
    assert out.returncode == 2 and "x.fmu': file not found" in out.stderr
    out = subprocess.run(
        [sys.executable, "-m", "koopbridge.adapters.fmu", str(damped_fmu), "--inputs", "u", "--outputs", "theta,phi"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2 and "unknown variable 'phi'" in out.stderr


def test_data_through_the_fmu_adapter_matches_the_reference(tmp_path, damped_fmu, session_id):
    ep = free_endpoint()
    ref = koopbridge.ReferenceSystem("damped-pendulum")
    with Child(fmu_adapter_cmd(damped_fmu, session_id, "fmu0", "--listen", ep), tmp_path / "adapter.log") as child:
        with koopbridge.Client(session=session_id, connect=[ep]) as c:
            info = c.connect_sim("fmu0", timeout=20)
            assert info["kind"] == "fmu" and info["state_names"] == ["theta", "omega"] and info["dt"] == 0.02
            rng = np.random.default_rng(11)
            worst = 0.0
            for w in range(5):  # five windows of 15 steps with uniform random inputs, as in SPEC
                x = c.reset("fmu0", seed=100 + w)
                assert np.all(np.abs(x) <= [2 * np.pi, 8])
                for k in range(15):
                    u = rng.uniform(-8, 8, size=1)
                    kk, t, nxt = c.step("fmu0", u)
                    assert kk == k + 1 and t == pytest.approx(0.02 * (k + 1))
                    worst = max(worst, float(np.max(np.abs(nxt - ref.step(x, u)))))
                    x = nxt
            assert worst < 1e-7, worst
            # A doStep failure (the state blows up) is a sim_failure reply naming the FMU...
            c.reset("fmu0", x0=[0.0, 0.0])
            with pytest.raises(koopbridge.RemoteError) as e:
                c.step("fmu0", [1e308])
            assert e.value.code == "sim_failure" and "damped_pendulum.fmu" in str(e.value) and "doStep failed" in str(e.value)
            # ...and the adapter serves on after a reset.
            np.testing.assert_array_equal(c.reset("fmu0", x0=[0.5, 0.0]), [0.5, 0.0])
            assert c.step("fmu0", [0.0])[0] == 1
        assert child.p.poll() is None, child.output()


def test_killed_adapter_is_named_within_a_second(tmp_path, damped_fmu, session_id):
    ep = free_endpoint()
    with Child(fmu_adapter_cmd(damped_fmu, session_id, "victim", "--listen", ep), tmp_path / "adapter.log") as child:
        with koopbridge.Client(session=session_id, connect=[ep]) as c:
            c.connect_sim("victim", timeout=20)
            c.reset("victim", x0=[0.1, 0.0])
            c.step("victim", [0.0])
            child.p.kill()
            child.p.wait()
            t0 = time.perf_counter()
            with pytest.raises(koopbridge.GoneError, match="simulator 'victim'"):
                c.step("victim", [0.0])
            assert time.perf_counter() - t0 < 1.0


def double_adapter_cmd(fmu, session: str, sim_id: str, *extra: str) -> list[str]:
    """The command line of the double-pendulum (FMI 3.0) FMU adapter as a child process."""
    return [
        sys.executable, "-m", "koopbridge.adapters.fmu", str(fmu),
        "--inputs", "u1,u2", "--outputs", "theta1,theta2,omega1,omega2", "--dt", "0.01",
        "--initial", "theta1_0,theta2_0,omega1_0,omega2_0", "--u-min=-5,-5", "--u-max=5,5",
        "--session", session, "--id", sim_id, *extra,
    ]  # fmt: skip


@pytest.mark.parametrize("which", ["damped", "double"])
def test_info_over_zenoh_carries_units_start_values_and_fmi_version(tmp_path, damped_fmu, double_fmu, session_id, which):
    ep = free_endpoint()
    if which == "damped":
        cmd, version = fmu_adapter_cmd(damped_fmu, session_id, "fmu0", "--listen", ep), "2.0"
        units = {"inputs": ["N"], "outputs": ["rad", "rad/s"]}
        start = {"g": 9.8, "max_substep": 0.001, "u": 0.0}
    else:
        cmd, version = double_adapter_cmd(double_fmu, session_id, "fmu0", "--listen", ep), "3.0"
        units = {"inputs": ["N.m", "N.m"], "outputs": ["rad", "rad", "rad/s", "rad/s"]}
        start = {"g": 9.8, "l1": 1.0, "m2": 1.0, "u2": 0.0}
    with Child(cmd, tmp_path / "adapter.log") as child:
        with koopbridge.Client(session=session_id, connect=[ep]) as c:
            info = c.connect_sim("fmu0", timeout=20)
        assert child.p.poll() is None, child.output()
    # What travelled over Zenoh, not what the Python object holds: the reply's `extra` object.
    fmu = info["extra"]["fmu"]
    assert fmu["fmi_version"] == version
    assert fmu["units"] == units
    by_name = {v["name"]: v for v in fmu["variables"]}
    for name, value in start.items():
        assert by_name[name]["start"] == value, (name, by_name[name])
    assert by_name[info["input_names"][0]]["causality"] == "input"
    assert all(by_name[n]["unit"] == u for n, u in zip(info["state_names"], units["outputs"], strict=False))
    assert info["version"].startswith(f"FMI {version}")


def test_info_extra_must_be_json(session_id):
    class Odd(koopbridge.Adapter):
        def info(self):
            return dict(env="odd", dt=0.1, state_names=["x"], input_names=[], u_min=[], u_max=[], blob=object())

        def reset(self, seed=None, x0=None):
            return np.zeros(1)

        def step(self, u):
            return np.zeros(1)

    with pytest.raises(ValueError, match="'blob' is not JSON-serialisable"):
        Odd().serve(session=session_id, id="odd")
