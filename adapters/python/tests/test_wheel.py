"""The abi3 wheel as a user who only wants the SDK gets it: built by scripts/build-wheel.sh,
installed offline into a fresh venv outside the repository, and a Python ``Simulator`` served
from that venv through a ``koopbridge serve`` router and stepped by the (Rust) ``Client``."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from conftest import ROOT, Child, free_endpoint, koopbridge_binary

MATURIN = ROOT / ".venv" / "bin" / "maturin"

# Run inside the fresh venv, from a folder outside the repository: serves Decay (x⁺ = a x + b u)
# as simulator `decay` through the router, steps it with the wheel's Client and checks every
# state against the closed form computed here with numpy.
USER_SCRIPT = """
import sys, threading
import numpy as np
import koopbridge
from koopbridge import SimInfo, SimulatorAdapter

session, endpoint, venv = sys.argv[1], sys.argv[2], sys.argv[3]
assert koopbridge.__file__.startswith(venv), f"koopbridge imported from {koopbridge.__file__}"

class Decay:
    A = np.array([[0.9, 0.1], [0.0, 0.8]])
    B = np.array([0.0, 0.5])

    def info(self):
        return SimInfo(env="decay", dt=0.1, state_names=["p", "v"], input_names=["f"],
                       u_min=[-1.0], u_max=[1.0])

    def reset(self, seed=None, x0=None):
        self.x = np.array(x0, float) if x0 is not None else np.random.default_rng(seed).uniform(-1, 1, 2)
        return self.x.copy()

    def step(self, u):
        self.x = self.A @ self.x + self.B * float(u[0])
        return self.x.copy()

adapter = SimulatorAdapter(Decay())
errors = []
def serve():
    try:
        adapter.serve(session=session, id="decay", connect=[endpoint], mode="client")
    except BaseException as e:
        errors.append(e)
t = threading.Thread(target=serve, daemon=True)
t.start()
with koopbridge.Client(session=session, connect=[endpoint], mode="client") as c:
    info = c.connect_sim("decay", timeout=30)
    assert info["env"] == "decay" and info["state_names"] == ["p", "v"], info
    x = c.reset("decay", x0=[1.0, -0.5])
    expect = np.array([1.0, -0.5])
    assert np.allclose(x, expect)
    for k in range(1, 21):
        u = np.sin(0.3 * k)
        kk, t_sim, x = c.step("decay", [u])
        expect = Decay.A @ expect + Decay.B * u
        assert kk == k and abs(t_sim - 0.1 * k) < 1e-9, (kk, t_sim)
        assert np.allclose(x, expect, rtol=0, atol=1e-12), (k, x, expect)
    # A wrong input length: a typed `dimension` error reply, and the adapter keeps serving.
    try:
        c.step("decay", [0.1, 0.2])
        raise AssertionError("a 2-value input was accepted")
    except koopbridge.RemoteError as e:
        assert e.code == "dimension", e.code
    assert c.step("decay", [0.0])[0] == 21
adapter.stop()
t.join(timeout=10)
assert not t.is_alive() and not errors, errors
print("wheel-sdk-ok", koopbridge.__version__)
"""


def _fresh_venv(where: Path) -> Path:
    """A new venv at ``where`` from the base interpreter (not this venv's packages)."""
    base = getattr(sys, "_base_executable", sys.executable)
    subprocess.run([base, "-m", "venv", str(where)], check=True)
    return where / "bin" / "python"


def test_wheel_installs_offline_and_serves_a_simulator(tmp_path_factory):
    if not MATURIN.exists():
        pytest.skip(f"maturin is not installed ({MATURIN}); scripts/setup-python.sh installs it")
    exe = koopbridge_binary()
    if exe is None:
        pytest.skip("the koopbridge CLI is not built (cargo build --release); scripts/test.sh builds it")
    t0 = time.monotonic()
    built = subprocess.run([str(ROOT / "scripts" / "build-wheel.sh")], check=True, capture_output=True, text=True)
    wheel = Path(built.stdout.strip().splitlines()[-1])
    assert wheel.is_file() and "-abi3-" in wheel.name, built.stdout + built.stderr

    tmp = tmp_path_factory.mktemp("wheel-user")
    assert ROOT not in tmp.parents
    py = _fresh_venv(tmp / "venv")
    # Offline: the wheel and its dependencies (numpy) from the wheelhouse the script fills,
    # plus /opt/wheels when the machine has one; never the index.
    links = [str(wheel.parent), str(wheel.parent / "deps")]
    if os.path.isdir("/opt/wheels"):
        links.append("/opt/wheels")
    cmd = [str(py), "-m", "pip", "install", "--quiet", "--no-index"]
    for link in links:
        cmd += ["--find-links", link]
    subprocess.run(cmd + [str(wheel)], check=True, cwd=tmp)

    session = "twheel" + os.urandom(4).hex()
    ep = free_endpoint()
    script = tmp / "user.py"
    script.write_text(textwrap.dedent(USER_SCRIPT))
    router = [str(exe), "serve", "models", "--session", session, "--mode", "router", "--listen", ep]
    router += ["--store", str(tmp / "models"), "--state-dir", str(tmp / "state"), "--stdin-lifeline"]
    with Child(router, tmp / "router.log") as r:
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
        run = subprocess.run(
            [str(py), str(script), session, ep, str(tmp / "venv")],
            cwd=tmp,
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert run.returncode == 0, f"{run.stdout}\n{run.stderr}\nrouter log:\n{r.output()}"
        assert "wheel-sdk-ok" in run.stdout
        assert r.p.poll() is None, "the router exited: " + r.output()
    print(f"wheel build + offline install + serve: {time.monotonic() - t0:.1f} s")
