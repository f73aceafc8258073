"""The main job's scenario, scenarios/damped-pendulum-fmu.toml, run by `koopbridge run` with a
tiny budget: the orchestrator starts the Python FMU adapter and the services, collects data
through the FMU, trains, regulates the FMU pendulum and writes a report. Killing the adapter
mid-run ends the run within a second naming it, and the same command then succeeds in the same
output folder."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import threading
import time
import tomllib

from conftest import ROOT, koopbridge_binary_or_skip

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
    assert len(x0) == len(lo) == len(hi) and all(a <= v <= b for a, v, b in zip(lo, x0, hi, strict=False))


def test_scenario_runs_end_to_end_with_a_tiny_budget(tmp_path, repo_tmp, damped_fmu):
    exe = koopbridge_binary_or_skip()
    text = SCENARIO.read_text()
    for key, value in (("train_windows", 64), ("val_windows", 16), ("test_windows", 16), ("steps = 200", None)):
        if value is None:
            text = text.replace("steps = 200", "steps = 30")
        else:
            text = re.sub(rf"^{key} = \d+", f"{key} = {value}", text, count=1, flags=re.M)
    text = text.replace("iterations = 3000, validate_every = 500", "iterations = 40, validate_every = 20")
    sc_file = repo_tmp / "tiny.toml"
    sc_file.write_text(text)
    out = tmp_path / "out"
    r = subprocess.run([str(exe), "run", str(sc_file), "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    text = json.dumps(report)
    assert "fmu" in text  # the simulator that answered is the FMU adapter
    assert list(out.glob("*.png")), "the report has plots"


def _child_with(parent: int, needle: bytes) -> int | None:
    """The pid of a child process of `parent` whose command line contains `needle`."""
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = open(f"/proc/{entry}/stat", "rb").read()
            cmd = open(f"/proc/{entry}/cmdline", "rb").read()
        except OSError:
            continue
        ppid = int(stat.rsplit(b")", 1)[1].split()[1])
        if ppid == parent and needle in cmd:
            return int(entry)
    return None


def test_killed_adapter_ends_the_run_within_a_second_and_a_rerun_needs_no_cleaning(tmp_path, repo_tmp, damped_fmu):
    exe = koopbridge_binary_or_skip()
    text = SCENARIO.read_text()
    for key, value in (("train_windows", 400), ("val_windows", 40), ("test_windows", 40)):
        text = re.sub(rf"^{key} = \d+", f"{key} = {value}", text, count=1, flags=re.M)
    text = text.replace("steps = 200", "steps = 20")
    text = re.sub(r"iterations = \d+, validate_every = \d+", "iterations = 40, validate_every = 20", text, count=1)
    sc_file = repo_tmp / "kill.toml"
    sc_file.write_text(text)
    out = tmp_path / "out"
    cmd = [str(exe), "run", str(sc_file), "--out", str(out)]
    run = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(b.decode(errors="replace") for b in run.stderr), daemon=True)
    reader.start()
    deadline = time.monotonic() + 120
    while not any("collecting" in line for line in lines):
        assert run.poll() is None, "".join(lines)
        assert time.monotonic() < deadline, "collection never started"
        time.sleep(0.01)
    time.sleep(0.5)  # mid-collection (it takes several seconds)
    adapter = _child_with(run.pid, b"koopbridge.adapters.fmu")
    assert adapter is not None and run.poll() is None, "".join(lines)
    t0 = time.monotonic()
    os.kill(adapter, signal.SIGKILL)
    code = run.wait(timeout=30)
    ended = time.monotonic() - t0
    reader.join(timeout=5)
    err = "".join(lines)
    assert code != 0 and "simulator 'pend'" in err, err
    print(f"the run ended {ended * 1000:.0f} ms after the FMU adapter was killed")
    assert ended < 1.0, f"the run took {ended:.2f} s to end after the adapter died:\n{err[-3000:]}"
    assert not (out / "report.json").exists()

    # The same command, the same output folder, nothing cleaned by hand.
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    assert report["collect"]["windows"] == [400, 40, 40]
    assert len(report["control"]["x"]) == 21
