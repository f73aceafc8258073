"""The control diagnosis names bad data: a simulator of the test's own (an unstable scalar plant,
x⁺ = 1.2 x + 0.1 u, that reports ``terminated`` once |x| > 1) collected with inputs far too
large, so that nearly every window ends; report.json's ``diagnoses[].data`` counts the windows
the simulator ended exactly as the test split shows them, and the missed goal's next step names
the collection as the cause (the MPC's bounds are too small to hold the plant, so the goal is
missed whatever the model)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np

from conftest import koopbridge_binary_or_skip

SIM = '''
import argparse, sys
import numpy as np
from koopbridge import SimInfo, run_main
from koopbridge.simulator import as_input, as_state


class Falls:
    def info(self):
        return SimInfo(env="falls", dt=0.1, state_names=["x"], input_names=["u"], u_min=[-5.0], u_max=[5.0])

    def reset(self, seed=None, x0=None):
        self.x = as_state(x0, 1) if x0 is not None else np.random.default_rng(seed).uniform(-0.2, 0.2, 1)
        return self.x.copy()

    def step(self, u):
        self.x = 1.2 * self.x + 0.1 * as_input(u, 1)
        return self.x.copy()

    def step_status(self):
        return {"terminated": bool(abs(self.x[0]) > 1.0)}


if __name__ == "__main__":
    sys.exit(run_main(lambda args: Falls(), argparse.ArgumentParser(prog="falls.py")))
'''

SCENARIO = """
name = "falls"

[[sims]]
id = "f"
command = ["{python}", "falls.py"]

[collect]
policy = { kind = "uniform", low = -5.0, high = 5.0 }
train_windows = 200
val_windows = 40
test_windows = 60
steps = 10

[train]
config = { iterations = 200, hidden = [16, 16], n_mult = 2, validate_every = 100 }

[control]
x0 = [0.5]
reference = [0.0]
steps = 40
mpc = { horizon = 10, u_min = [-0.001], u_max = [0.001] }
"""


def test_windows_the_simulator_ended_are_counted_and_named(tmp_path):
    exe = koopbridge_binary_or_skip()
    (tmp_path / "falls.py").write_text(textwrap.dedent(SIM))
    (tmp_path / "falls.toml").write_text(SCENARIO)
    env = {k: v for k, v in os.environ.items() if k != "KOOPBRIDGE_PYTHON"}
    env["KOOPBRIDGE_PYTHON"] = sys.executable
    out = tmp_path / "out"
    r = subprocess.run([str(exe), "run", "falls.toml", "--out", str(out)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]

    with np.load(out / "data" / "f" / "test.npz") as d:
        x = d["x"]
    # A window counts once if any state after a step is beyond the stop (the step's flag).
    ended = int(np.sum(np.any(np.abs(x[:, 1:, 0]) > 1.0, axis=1)))
    assert 0.2 * len(x) < ended <= len(x)
    report = json.loads((out / "report.json").read_text())
    (d,) = report["diagnoses"]
    assert d["data"]["windows"] == len(x)
    assert d["data"]["window_flags"]["terminated"] == ended
    assert d["data"]["window_flags"]["clipped"] == 0
    share = round(100 * ended / len(x))
    assert report["control"]["time_to_goal_steps"] is None
    assert d["next_step"].startswith(f"{share}% of the collection windows reached a state where the simulator ended"), d["next_step"]
    assert any(f"next: {share}% of the collection windows" in w for w in report["warnings"]), report["warnings"]
