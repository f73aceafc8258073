"""`python -m koopbridge.adapters.mujoco` as a child process: --help, --describe, and lockstep
steps over Zenoh equal, bit for bit, the same simulator stepped in this process; SIGTERM ends
it cleanly with its counters; an unstable step is a sim_failure and MuJoCo's warning goes to the
adapter's stderr."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("mujoco")

import koopbridge  # noqa: E402
from conftest import Child, free_endpoint  # noqa: E402
from koopbridge.adapters.mujoco.sim import FrankaSimulator  # noqa: E402

MODULE = [sys.executable, "-m", "koopbridge.adapters.mujoco"]


class ChildIn(Child):
    """A child process started in folder ``cwd``."""

    def __init__(self, cwd, cmd, log) -> None:
        self.log = log
        self.f = open(log, "wb")
        self.p = subprocess.Popen(cmd, stdout=self.f, stderr=subprocess.STDOUT, stdin=subprocess.PIPE, cwd=cwd)


def test_help_and_describe():
    out = subprocess.run(MODULE + ["--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "--state" in out.stdout and "--free-run" in out.stdout and "--describe" in out.stdout
    out = subprocess.run(MODULE + ["--describe", "--state", "q,qd"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout)
    assert info["kind"] == "mujoco" and len(info["state_names"]) == 14 and info["u_max"] == [0.3] * 7
    assert info["mujoco"]["actuation"]["gravcomp"] is True and info["mujoco"]["model_file"].endswith("panda/robot.xml")


def test_child_adapter_matches_in_process_and_stops_on_sigterm(tmp_path, session_id):
    ep = free_endpoint()
    here = FrankaSimulator()
    rng = np.random.default_rng(5)
    us = rng.uniform(-0.12, 0.12, size=(20, 7))
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    with ChildIn(cwd, MODULE + ["--session", session_id, "--id", "arm0", "--listen", ep], tmp_path / "adapter.log") as child:
        with koopbridge.Client(session=session_id, connect=[ep]) as c:
            info = c.connect_sim("arm0", timeout=30)
            assert info["kind"] == "mujoco" and info["env"] == "franka-panda" and info["extra"]["mujoco"]["substeps"] == 10
            np.testing.assert_array_equal(c.reset("arm0", seed=11), here.reset(seed=11))
            for i, u in enumerate(us):
                k, t, x = c.step("arm0", u)
                assert k == i + 1 and t == pytest.approx(0.02 * (i + 1))
                np.testing.assert_array_equal(x, here.step(u))
            # An unstable start (q̇ beyond MuJoCo's 1e10 limit) fails the step, the adapter
            # logs MuJoCo's warning to stderr (no MUJOCO_LOG.TXT) and serves on.
            x0 = here.reset(seed=11)
            x0[10] = 1e11
            c.reset("arm0", x0=x0)
            with pytest.raises(koopbridge.RemoteError) as e:
                c.step("arm0", np.zeros(7))
            assert e.value.code == "sim_failure" and "unstable" in str(e.value)
            np.testing.assert_array_equal(c.reset("arm0", seed=11), here.reset(seed=11))
        child.p.send_signal(signal.SIGTERM)
        assert child.p.wait(timeout=10) == 0, child.output()
        log = child.output()
    assert "koopbridge mujoco adapter: franka-panda as sim 'arm0'" in log and "stopped after 20 steps" in log, log
    assert "MuJoCo warning: Nan, Inf or huge value in QVEL" in log and list(cwd.iterdir()) == [], log


def test_free_run_in_real_time_publishes_every_step(session_id):
    # dt = 0.02 s: 25 steps at the default rate (real time) take half a second.
    ad = koopbridge.SimulatorAdapter(FrankaSimulator())
    stats = ad.serve(session=session_id, id="fr", free_run=True, steps=25, seed=4)
    assert stats["steps"] == 25 and stats["published"] == 26, stats
    assert 0.5 < stats["real_time_factor"] < 1.5, stats
    # No command arrived: the arm held zero velocity commands from its seeded start.
    start = FrankaSimulator().reset(seed=4)
    assert np.abs(ad.sim.state()[3:10] - start[3:10]).max() < 0.01
