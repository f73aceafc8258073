"""The main job's scenario, scenarios/damped-pendulum-fmu.toml, run by `koopbridge run` with a
tiny budget: the orchestrator starts the Python FMU adapter and the services, collects data
through the FMU, trains, regulates the FMU pendulum and writes a report."""

from __future__ import annotations

import json
import re
import subprocess
import tomllib

import pytest

from conftest import ROOT, koopbridge_binary

SCENARIO = ROOT / "scenarios" / "damped-pendulum-fmu.toml"


def test_scenario_file_is_consistent():
    sc = tomllib.loads(SCENARIO.read_text())
    (sim,) = sc["sims"]
    cmd = sim["command"]
    assert cmd[:3] == ["{python}", "-m", "koopbridge.adapters.fmu"]
    assert (ROOT / cmd[3]).parent == ROOT / "adapters" / "fmu" / "build"
    assert sc["collect"]["steps"] == 15
    # The control task starts inside the region the data is collected from (the model is local).
    flag = {a.split("=")[0]: [float(v) for v in a.split("=")[1].split(",")] for a in cmd if a.startswith("--x0-")}
    lo, hi, x0 = flag["--x0-low"], flag["--x0-high"], sc["control"]["x0"]
    assert len(x0) == len(lo) == len(hi) and all(a <= v <= b for a, v, b in zip(lo, x0, hi))


def test_scenario_runs_end_to_end_with_a_tiny_budget(tmp_path, damped_fmu):
    exe = koopbridge_binary()
    if exe is None:
        pytest.skip("the koopbridge CLI is not built (cargo build --release); scripts/test.sh builds it")
    text = SCENARIO.read_text()
    for key, value in (("train_windows", 64), ("val_windows", 16), ("test_windows", 16), ("steps = 200", None)):
        if value is None:
            text = text.replace("steps = 200", "steps = 30")
        else:
            text = re.sub(rf"^{key} = \d+", f"{key} = {value}", text, count=1, flags=re.M)
    text = text.replace("iterations = 3000, validate_every = 500", "iterations = 40, validate_every = 20")
    sc_file = tmp_path / "tiny.toml"
    sc_file.write_text(text)
    out = tmp_path / "out"
    r = subprocess.run([str(exe), "run", str(sc_file), "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    text = json.dumps(report)
    assert "fmu" in text  # the simulator that answered is the FMU adapter
    assert list(out.glob("*.png")), "the report has plots"
