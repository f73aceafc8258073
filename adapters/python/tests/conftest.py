"""Shared fixtures: the project's FMUs (built by adapters/fmu/build.sh if missing), fresh
koopbridge session ids, adapters served in a background thread or a child process, the CLI
binary, and the reset rule of the test simulators."""

from __future__ import annotations

import os
import subprocess
import sys
import uuid
from pathlib import Path
from typing import Self

import numpy as np
import pytest

from koopbridge.testing import ServedOnThread

ROOT = Path(__file__).resolve().parents[3]
FMU_DIR = ROOT / "adapters" / "fmu" / "build"


def _fmu(name: str) -> Path:
    path = FMU_DIR / f"{name}.fmu"
    if not path.exists():
        subprocess.run(
            [str(ROOT / "adapters" / "fmu" / "build.sh")],
            check=True,
            env={**os.environ, "PYTHON": sys.executable},
        )
    return path


@pytest.fixture(scope="session")
def damped_fmu() -> Path:
    return _fmu("damped_pendulum")


@pytest.fixture(scope="session")
def double_fmu() -> Path:
    return _fmu("double_pendulum")


@pytest.fixture
def session_id() -> str:
    """A fresh koopbridge session id, so that tests never see each other's participants."""
    return "t" + uuid.uuid4().hex[:12]


@pytest.fixture
def serve_in_thread():
    """``koopbridge.testing.ServedOnThread``: an adapter served on a background thread."""
    return ServedOnThread


def fmu_adapter_cmd(fmu: Path, session: str, sim_id: str, *extra: str) -> list[str]:
    """The command line of the damped-pendulum FMU adapter as a child process."""
    return [
        sys.executable,
        "-m",
        "koopbridge.adapters.fmu",
        str(fmu),
        "--inputs",
        "u",
        "--outputs",
        "theta,omega",
        "--dt",
        "0.02",
        "--initial",
        "theta0,omega0",
        "--x0-low=-6.283185307179586,-8",
        "--x0-high=6.283185307179586,8",
        "--u-min=-8",
        "--u-max=8",
        "--env",
        "damped-pendulum",
        "--angles",
        "0",
        "--session",
        session,
        "--id",
        sim_id,
        *extra,
    ]


def free_endpoint() -> str:
    """A free TCP port on 127.0.0.1 as a Zenoh endpoint."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def koopbridge_binary() -> Path | None:
    """The `koopbridge` CLI built by cargo (release), if any (``koopbridge.cli_path.find_cli``)."""
    from koopbridge.cli_path import find_cli

    return find_cli()


def reset_state(seed: int | None, x0, n: int = 2) -> np.ndarray:
    """The reset rule of the test simulators: ``x0`` if given, else a state drawn uniformly in
    [-1, 1]^n with ``seed``, else zeros."""
    if x0 is not None:
        return np.array(x0, dtype=float)
    if seed is not None:
        return np.random.default_rng(seed).uniform(-1, 1, n)
    return np.zeros(n)


def koopbridge_binary_or_skip() -> Path:
    """``koopbridge_binary()``, or the calling test is skipped when the CLI is not built."""
    exe = koopbridge_binary()
    if exe is None:
        pytest.skip("the koopbridge CLI is not built (cargo build --release); scripts/test.sh builds it")
    return exe


def scenario_env(exe: Path) -> dict[str, str]:
    """The environment of a ``koopbridge run`` outside the repository: ``KOOPBRIDGE_PYTHON``
    unset (the binary finds the venv it was built in), or this Python when the binary has no
    venv above it."""
    env = {k: v for k, v in os.environ.items() if k != "KOOPBRIDGE_PYTHON"}
    if not any((d / ".venv" / "bin" / "python").is_file() for d in exe.resolve().parents):
        env["KOOPBRIDGE_PYTHON"] = sys.executable  # a binary installed elsewhere: name the Python
    return env


def run_shipped_scenario(tmp_path: Path, name: str, smoke: dict[str, int], replace: list[tuple[str, str]]) -> tuple[str, Path]:
    """``scenarios/NAME.toml`` cut to a smoke budget (``smoke``: ``key = N`` lines rewritten,
    ``replace``: exact texts swapped, each required to be there) and run from a folder outside
    the repository; returns the shipped text and the output folder (the run must succeed)."""
    import re

    exe = koopbridge_binary_or_skip()
    text = (ROOT / "scenarios" / f"{name}.toml").read_text()
    shipped = text
    for key, value in smoke.items():
        text, n = re.subn(rf"^{key} = \d+", f"{key} = {value}", text, count=1, flags=re.M)
        assert n == 1, key
    for old, new in replace:
        assert old in text, old
        text = text.replace(old, new)
    sc = tmp_path / "elsewhere" / f"{name}.toml"
    sc.parent.mkdir()
    sc.write_text(text)
    out = tmp_path / "out"
    r = subprocess.run([str(exe), "run", str(sc), "--out", str(out)], cwd=tmp_path, env=scenario_env(exe), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    return shipped, out


class Child:
    """A child process with its output in a log file; killed on exit."""

    def __init__(self, cmd: list[str], log: Path) -> None:
        self.log = log
        self.f = open(log, "wb")
        self.p = subprocess.Popen(cmd, stdout=self.f, stderr=subprocess.STDOUT, stdin=subprocess.PIPE)

    def output(self) -> str:
        self.f.flush()
        return self.log.read_text(errors="replace")

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        if self.p.poll() is None:
            self.p.kill()
        self.p.wait(timeout=10)
        self.f.close()


@pytest.fixture
def repo_tmp():
    """A temporary folder inside the repository (under target/, which git ignores): a scenario
    file written there has the repository as its base, so its relative paths and ``{python}``
    (the repository's venv) resolve as for the real scenario files."""
    import shutil
    import tempfile

    base = ROOT / "target"
    base.mkdir(exist_ok=True)
    d = Path(tempfile.mkdtemp(prefix="pytest-scenario-", dir=base))
    yield d
    shutil.rmtree(d, ignore_errors=True)


def idp_scenario(name: str, steps: int) -> str:
    """A small Gymnasium InvertedDoublePendulum-v5 scenario (the shipped one's data box and MPC,
    EDMD only, a few hundred windows; `steps` closed-loop steps) for the live view's tests."""
    return f"""
name = "{name}"
[[sims]]
id = "cart"
command = ["{{python}}", "-m", "koopbridge.adapters.gym", "InvertedDoublePendulum-v5", "--quiet"]
[collect]
policy = {{ kind = "uniform", low = -0.1, high = 0.1 }}
x0_center = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
x0_radius = [0.05, 0.03, 0.03, 0.1, 0.1, 0.1]
train_windows = 200
val_windows = 40
test_windows = 40
steps = 5
seed = 42
[train]
model = "edmd"
[control]
x0 = [0.0, 0.05, 0.05, 0.0, 0.0, 0.0]
reference = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
steps = {steps}
mpc = {{ horizon = 30, q = [10.0, 10.0, 10.0, 0.1, 0.1, 0.1], r = [0.3] }}
"""
