"""The Simulator SDK: SimInfo's checks and its round trip to the dict the Rust side reads,
SimulatorAdapter's input checks, listening_client's retry of a taken port, check_adapter passing
a correct simulator (a Python one and the FMU) and catching broken ones, BridgeTimeout, and
run_main's exit codes."""

from __future__ import annotations

import argparse
import builtins

import numpy as np
import pytest

import koopbridge
from conftest import reset_state
from koopbridge import InvalidInput, SimInfo, SimulatorAdapter, Unsupported
from koopbridge.adapters.fmu.sim import FmuSimulator
from koopbridge.testing import check_adapter, listening_client


class Decay:
    """x⁺ = a x + b u in 2-D; seeded reset draws x0 in [-1, 1]²."""

    def __init__(self, a: float = 0.9) -> None:
        self.a = a
        self.x = np.zeros(2)

    def info(self) -> SimInfo:
        return SimInfo(env="decay", dt=0.1, state_names=["p", "v"], input_names=["f"], u_min=[-1.0], u_max=[1.0], extra={"units": ["m", "m/s"]})

    def reset(self, seed=None, x0=None):
        self.x = reset_state(seed, x0)
        return self.x.copy()

    def step(self, u):
        u = np.asarray(u, float)
        if u.shape != (1,):
            raise InvalidInput(f"u must have 1 value, got {u.size}")
        self.x = self.a * self.x + np.array([0.0, 0.1]) * u[0]
        return self.x.copy()


def test_siminfo_round_trips_and_reads_like_the_old_dict():
    info = Decay().info()
    d = info.to_dict()
    assert d["env"] == "decay" and d["units"] == ["m", "m/s"] and "extra" not in d
    assert SimInfo.from_dict(d) == info
    assert info["dt"] == 0.1 and info["units"] == ["m", "m/s"] and info.nx == 2 and info.nu == 1
    assert set(info) == set(d)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(dt=0.0), "dt must be positive"),
        (dict(u_max=[1.0, 2.0]), "1 input names but 1 u_min and 2 u_max"),
        (dict(u_min=[2.0]), "has bounds \\[2.0, 1.0\\]"),
        (dict(angle_indices=[2]), "angle index 2 is outside"),
        (dict(extra={"dt": 1}), "extra key 'dt' is a field name"),
        (dict(extra={"blob": object()}), "extra\\['blob'\\] is not JSON-serialisable"),
        (dict(extra={"bad": float("nan")}), "not JSON-serialisable"),
    ],
)
def test_siminfo_refuses_what_the_bridge_would(change, message):
    base = dict(env="e", dt=0.1, state_names=["x"], input_names=["u"], u_min=[-1.0], u_max=[1.0])
    with pytest.raises(ValueError, match=message):
        SimInfo(**{**base, **change})


def test_simulator_adapter_checks_inputs_before_the_simulator():
    sim = Decay()
    ad = SimulatorAdapter(sim)
    assert ad.info()["env"] == "decay"
    ad.reset(seed=1)
    with pytest.raises(InvalidInput, match="u must have 1 values, got 2"):
        ad.step([0.1, 0.2])
    with pytest.raises(InvalidInput, match="u must be finite"):
        ad.step([np.nan])
    with pytest.raises(InvalidInput, match="x0 must have 2 values, got 3"):
        ad.reset(x0=[1, 2, 3])
    x = ad.step([0.5])
    assert x.dtype == np.float64 and x.shape == (2,)
    with pytest.raises(TypeError, match="is not a koopbridge Simulator"):
        SimulatorAdapter(object())


def test_check_adapter_passes_a_correct_simulator():
    info = check_adapter(Decay())
    assert info.env == "decay"


def test_listening_client_takes_another_port_when_the_probed_one_is_taken(monkeypatch):
    import socket

    import koopbridge.testing as kt

    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    probes = [f"tcp/127.0.0.1:{taken.getsockname()[1]}"]
    real = kt._free_endpoint
    monkeypatch.setattr(kt, "_free_endpoint", lambda: probes.pop(0) if probes else real())
    try:
        client, ep = kt.listening_client("lc" + str(taken.getsockname()[1]))
        with client:
            assert ep != f"tcp/127.0.0.1:{taken.getsockname()[1]}" and not probes
        probes.append(f"tcp/127.0.0.1:{taken.getsockname()[1]}")
        with pytest.raises(koopbridge.KoopbridgeError, match="Address already in use"):
            kt.listening_client("lc", tries=1)
    finally:
        taken.close()


def test_check_adapter_passes_the_fmu(damped_fmu):
    sim = FmuSimulator(
        str(damped_fmu), ["u"], ["theta", "omega"], dt=0.02, initial=["theta0", "omega0"], x0_low=[-1, -1], x0_high=[1, 1], u_min=[-8], u_max=[8]
    )
    try:
        assert check_adapter(sim).kind == "fmu"
    finally:
        sim.close()


class Noisy(Decay):
    def step(self, u):
        return super().step(u) + np.random.default_rng().normal(0, 1e-3, 2)


class IgnoresSeed(Decay):
    def reset(self, seed=None, x0=None):
        return super().reset(seed=None, x0=x0)


class AcceptsAnything(Decay):
    def step(self, u):
        self.x = self.a * self.x
        return self.x.copy()


class HiddenState(Decay):
    """The returned state omits a velocity it keeps: reset(x0) cannot reproduce the run."""

    def reset(self, seed=None, x0=None):
        self.hidden = 0.0
        return super().reset(seed, x0)

    def step(self, u):
        self.hidden += 0.1
        return super().step(u) + self.hidden


class ListInfo(Decay):
    def info(self):
        return self.info_dict()

    def info_dict(self):
        return super().info().to_dict()


@pytest.mark.parametrize(
    "sim, message",
    [
        (Noisy(), "not deterministic"),
        (IgnoresSeed(), "the seed is ignored"),
        (AcceptsAnything(), "step\\(\\) accepted 2 input values"),
        (HiddenState(), "the state does not determine the next one"),
        (ListInfo(), "info\\(\\) returned dict, expected a koopbridge.SimInfo"),
    ],
)
def test_check_adapter_catches_broken_simulators(sim, message):
    with pytest.raises(AssertionError, match=message):
        check_adapter(sim, zenoh=False)


def test_check_adapter_skips_what_a_simulator_says_it_does_not_support():
    class NoX0(Decay):
        def reset(self, seed=None, x0=None):
            if x0 is not None:
                raise Unsupported("no x0 here")
            return super().reset(seed=seed)

    assert check_adapter(NoX0()).env == "decay"


def test_bridge_timeout_is_both_kinds_and_does_not_shadow_the_builtin():
    assert issubclass(koopbridge.BridgeTimeout, koopbridge.KoopbridgeError)
    assert issubclass(koopbridge.BridgeTimeout, builtins.TimeoutError)
    assert not hasattr(koopbridge, "TimeoutError")
    ns: dict = {}
    exec("from koopbridge import *", ns)
    assert "TimeoutError" not in ns
    with koopbridge.Client(session="tnobody") as c:
        with pytest.raises(builtins.TimeoutError, match="nobody-here"):
            c.query("nobody-here", b"", timeout=0.3)


def test_run_main_exit_codes(capsys):
    def factory(args):
        if args.broken:
            raise koopbridge.KoopbridgeError("this simulator cannot start")
        return Decay()

    def parser():
        p = argparse.ArgumentParser(prog="decay")
        p.add_argument("--broken", action="store_true")
        return p

    assert koopbridge.run_main(factory, parser(), ["--broken"]) == 2
    assert "error: this simulator cannot start" in capsys.readouterr().err
    assert koopbridge.run_main(factory, parser(), ["--describe"]) == 0
    out = capsys.readouterr().out
    assert '"env": "decay"' in out and '"units": [' in out
    # A free run with a step limit serves, returns 0 and prints the counters.
    assert koopbridge.run_main(factory, parser(), ["--free-run", "--rate", "500", "--steps", "4", "--seed", "3"]) == 0
    err = capsys.readouterr().err
    assert "koopbridge python adapter: decay as sim 'sim0'" in err and "stopped after 4 steps" in err and '"published": 5' in err


def test_simulator_adapter_collects_through_any_simulator():
    from koopbridge.collect import UniformPolicy, collect_windows, window_rng

    ad = SimulatorAdapter(Decay())
    w = ad.collect({"kind": "uniform"}, seed=4, n_windows=3, T=5)
    assert w.x.shape == (3, 6, 2) and w.u.shape == (3, 5, 1)
    # Window i is the generic loop's, drawn from window_rng(seed, i) alone.
    again = collect_windows(Decay(), UniformPolicy(), 4, 3, 5)
    assert np.array_equal(w.x, again.x) and np.array_equal(w.u, again.u)
    rng = window_rng(4, 2)
    assert int(w.reset_seeds[2]) == int(rng.integers(0, 2**63))
    np.testing.assert_array_equal(w.u[2], rng.uniform([-1.0], [1.0], size=(5, 1)))
    np.testing.assert_array_equal(w.x[2, 0], Decay().reset(seed=int(w.reset_seeds[2])))


def test_siminfo_from_an_info_reply(session_id, serve_in_thread):
    client, ep = listening_client(session_id)
    with serve_in_thread(SimulatorAdapter(Decay()), session=session_id, id="d", connect=[ep]):
        with client as c:
            reply = c.connect_sim("d", timeout=10)
    info = SimInfo.from_dict(reply)
    assert info.env == "decay" and info.extra["units"] == ["m", "m/s"] and info.nx == 2


def test_check_adapter_handles_a_simulator_without_inputs():
    class Autonomous(Decay):
        def info(self):
            return SimInfo(env="auto", dt=0.1, state_names=["p", "v"], input_names=[], u_min=[], u_max=[])

        def step(self, u):
            if np.asarray(u).size != 0:
                raise InvalidInput("no inputs")
            self.x = self.a * self.x
            return self.x.copy()

    assert check_adapter(Autonomous()).nu == 0


_INTERRUPTIBLE = """
import argparse, numpy as np, koopbridge
class Hold:
    def info(self):
        return koopbridge.SimInfo(env="hold", dt=0.01, state_names=["x"], input_names=["u"], u_min=[-1.0], u_max=[1.0])
    def reset(self, seed=None, x0=None):
        self.x = np.zeros(1)
        return self.x
    def step(self, u):
        return self.x
raise SystemExit(koopbridge.run_main(lambda a: Hold(), argparse.ArgumentParser(prog="hold"),
                                     ["--free-run", "--rate", "200", "--session", SESSION]))
"""


def test_run_main_prints_the_counters_after_ctrl_c(session_id):
    """Ctrl-C (SIGINT) ends an unlimited free run with exit code 130 and still prints the
    adapter's counters: the worker thread's stats are kept on the adapter (``last_stats``)."""
    import signal
    import subprocess
    import sys
    import time

    code = _INTERRUPTIBLE.replace("SESSION", repr(session_id))
    # A test run started in the background (`nohup … &`) hands its children SIGINT ignored, and
    # Python then installs no handler for it: restore the default so that Ctrl-C is Ctrl-C.
    p = subprocess.Popen([sys.executable, "-c", code], stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        assert p.stderr is not None
        first = p.stderr.readline()
        assert "as sim 'sim0'" in first, first
        time.sleep(1.0)  # about 200 ticks at 200 Hz
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=20)
        assert p.returncode == 130, err
    finally:
        p.kill()
    assert "interrupted after" in err, err
    steps = int(err.split("interrupted after ")[1].split(" ")[0])
    assert steps > 20, err
    assert '"published": ' in err and f'"steps": {steps}' in err, err
