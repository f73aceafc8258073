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
