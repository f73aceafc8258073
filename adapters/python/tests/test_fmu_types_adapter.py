"""The FMU adapter as a child process with the typed test FMUs, driven over Zenoh by
koopbridge.Client: typed inputs and outputs and array elements on the wire, unrepresentable
values as bad_request replies naming the variable (the adapter serving on), start-up refusals
(exit 2), strict JSON from --describe, and a clean exit on SIGTERM with --stdin-lifeline."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import koopbridge
from conftest import Child, _fmu, free_endpoint

MODULE = [sys.executable, "-m", "koopbridge.adapters.fmu"]


def typed3_cmd(session: str, sim_id: str, *extra: str) -> list[str]:
    """typed_fmi3 served with an Int32, Boolean, Enumeration, Float32 and UInt8 input and
    outputs of those types plus the array y (n = 4 via --param)."""
    return [
        *MODULE, str(_fmu("typed_fmi3")), "--inputs", "drive,on,mode,gain,u8",
        "--outputs", "x,steps,xf,u8_out,on_out,mode_out,y", "--dt", "0.05",
        "--param", "n=4", "--param", "x0=0.5", "--session", session, "--id", sim_id, *extra,
    ]  # fmt: skip


def test_typed_values_over_zenoh_and_bad_values_as_bad_request(tmp_path, session_id):
    ep = free_endpoint()
    with Child(typed3_cmd(session_id, "typed", "--listen", ep), tmp_path / "adapter.log") as child:
        with koopbridge.Client(session=session_id, connect=[ep]) as c:
            info = c.connect_sim("typed", timeout=20)
            assert info["state_names"] == ["x", "steps", "xf", "u8_out", "on_out", "mode_out", "y[0]", "y[1]", "y[2]", "y[3]"]
            assert info["u_min"] == [-1000, 0, 1, 0, 0] and info["u_max"] == [1000, 1, 3, 10, 200]
            np.testing.assert_array_equal(c.reset("typed"), [0.5, 0, 0.5, 0, 0, 1, 0.5, 1.0, 1.5, 2.0])
            x, k = 0.5, 0
            rng = np.random.default_rng(3)
            for _ in range(20):
                u = [
                    float(rng.integers(-1000, 1001)),
                    float(rng.integers(0, 2)),
                    float(rng.integers(1, 4)),
                    float(np.float32(rng.uniform(0, 10))),
                    float(rng.integers(0, 201)),
                ]
                k, _, got = c.step("typed", u)
                if u[1]:
                    x += 0.05 * u[3] * u[0] * {1: 1.0, 2: -1.0, 3: 0.0}[int(u[2])]
                np.testing.assert_array_equal(got, [x, k, float(np.float32(x)), u[4], u[1], u[2], x, 2 * x, 3 * x, 4 * x])
            for bad, name, value in [
                ([1.5, 1, 1, 1, 0], "drive", "1.5"),
                ([1, 2, 1, 1, 0], "on", "2.0"),
                ([1, 1, 1, 1, 300], "u8", "300.0"),
                ([1, 1, 1, 1, 201], "u8", "201.0"),
            ]:
                with pytest.raises(koopbridge.RemoteError) as e:
                    c.step("typed", bad)
                assert e.value.code == "bad_request", e.value
                assert f"'{name}'" in str(e.value) and f"cannot take {value}" in str(e.value) and "typed_fmi3.fmu" in str(e.value)
            with pytest.raises(koopbridge.KoopbridgeError, match="finite"):  # NaN: refused before the FMU
                c.step("typed", [float("nan"), 1, 1, 1, 0])
            # The adapter serves on: the next step continues from step k.
            assert c.step("typed", [0, 0, 1, 1, 0])[0] == k + 1
        assert child.p.poll() is None, child.output()


def test_unservable_variables_fail_at_start_up_not_at_reset(tmp_path):
    fmu = str(_fmu("typed_fmi3"))
    for extra, msg in [
        (["--inputs", "drive", "--outputs", "x,label"], "variable 'label' is of type String"),
        (["--inputs", "blob", "--outputs", "x"], "variable 'blob' is of type Binary"),
        (["--inputs", "drive", "--outputs", "y", "--param", "n=12"], "parameter 'n' (UInt64) cannot take 12.0: outside 1..8"),
    ]:
        out = subprocess.run([*MODULE, fmu, *extra, "--describe"], capture_output=True, text=True, timeout=60)
        assert out.returncode == 2 and msg in out.stderr, out.stderr


def test_describe_is_strict_json_with_null_for_no_bound():
    out = subprocess.run(
        [*MODULE, str(_fmu("typed_fmi2")), "--inputs", "drive,gain", "--outputs", "x,steps", "--describe"], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert "Infinity" not in out.stdout and "NaN" not in out.stdout

    def no_constants(name):
        raise AssertionError(f"{name} in --describe output")

    info = json.loads(out.stdout, parse_constant=no_constants)
    assert info["u_min"] == [-1000, None] and info["u_max"] == [1000, None]
    assert info["fmu"]["types"] == {"inputs": ["Integer", "Real"], "outputs": ["Real", "Integer"]}


def test_sigterm_with_stdin_lifeline_and_stdin_open_exits_cleanly(tmp_path, session_id):
    # Before the fix the lifeline thread held the lock of sys.stdin's buffered reader and
    # interpreter shutdown aborted (exit -6, "could not acquire lock for <_io.BufferedReader ...>").
    cmd = typed3_cmd(session_id, "term", "--listen", free_endpoint(), "--stdin-lifeline")
    with Child(cmd, tmp_path / "adapter.log") as child:
        deadline = time.time() + 30
        while "as sim 'term'" not in child.output() and time.time() < deadline and child.p.poll() is None:
            time.sleep(0.1)
        assert "as sim 'term'" in child.output(), child.output()
        time.sleep(0.3)  # the lifeline thread is blocked reading stdin
        child.p.send_signal(signal.SIGTERM)
        rc = child.p.wait(timeout=20)
        assert child.p.stdin is not None and not child.p.stdin.closed  # stdin stayed open throughout
        assert rc == 0, (rc, child.output())
        assert "could not acquire lock" not in child.output() and "stopped after" in child.output()


def test_stdin_lifeline_still_stops_the_adapter_when_stdin_closes(tmp_path, session_id):
    cmd = typed3_cmd(session_id, "eof", "--listen", free_endpoint(), "--stdin-lifeline")
    with Child(cmd, tmp_path / "adapter.log") as child:
        deadline = time.time() + 30
        while "as sim 'eof'" not in child.output() and time.time() < deadline and child.p.poll() is None:
            time.sleep(0.1)
        assert child.p.stdin is not None
        child.p.stdin.close()
        assert child.p.wait(timeout=20) == 0, child.output()
