"""The run's view (issue 45): `koopbridge run --record-view` over a real session writes view.rrd,
read back with Rerun's own reader against report.json; bad input to the viewer gets a clear
message and never stops the run."""

from __future__ import annotations

import json
import os
import subprocess
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from conftest import idp_scenario, koopbridge_binary_or_skip, scenario_env  # noqa: E402
from koopbridge.view import loop_path, state_groups  # noqa: E402

SCENARIO = """
name = "view-test"
[[sims]]
id = "pend-a"
env = "damped-pendulum"
[[sims]]
id = "pend-b"
env = "damped-pendulum"
[collect]
policy = { kind = "uniform" }
train_windows = 120
val_windows = 20
test_windows = 2
steps = 15
seed = 42
[train]
config = { iterations = 60, validate_every = 20, hidden = [32], n_mult = 2 }
[[control]]
sim = "pend-a"
x0 = [-1.0, 0.1]
reference = [0.0, 0.0]
steps = 30
mpc = { horizon = 10 }
[[control]]
sim = "pend-b"
references = "{out}/data/pend-b/test.npz"
"""


def read_rows(path: Path) -> dict[str, list[tuple[int | None, list[float]]]]:
    """Every temporal row of the recording's scalar entities: entity -> [(step, values)]."""
    out: dict[str, list[tuple[int | None, list[float]]]] = defaultdict(list)
    for c in RrdReader(path).stream():
        if c.is_static:
            continue
        b = c.to_record_batch()
        if "Scalars:scalars" not in b.schema.names:
            out[c.entity_path].extend((None, []) for _ in range(c.num_rows))
            continue
        steps = b.column("step").to_pylist() if "step" in b.schema.names else [None] * c.num_rows
        values = b.column("Scalars:scalars").to_pylist()
        out[c.entity_path].extend(zip(steps, values, strict=True))
    for rows in out.values():
        rows.sort(key=lambda r: -1 if r[0] is None else r[0])
    return out


def run(tmp_path: Path, *extra: str) -> tuple[subprocess.CompletedProcess[str], Path]:
    exe = koopbridge_binary_or_skip()
    sc = tmp_path / "view-test.toml"
    sc.write_text(SCENARIO)
    out = tmp_path / "out"
    r = subprocess.run(
        [str(exe), "run", str(sc), "--out", str(out), *extra],
        cwd=tmp_path,
        env=scenario_env(exe),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    return r, out


def test_recorded_view_holds_every_state_plan_and_loss_of_the_report(tmp_path):
    _, out = run(tmp_path, "--record-view")
    report = json.loads((out / "report.json").read_text())
    rrd = out / "view.rrd"
    assert report["view"] == str(rrd) and rrd.is_file() and not (out / "view.rrd.part").exists()
    rows = read_rows(rrd)

    # The [control] loop: one row per state, the last equal to the report's; a plan per decision
    # starting at the state it was made from; a solve time per decision.
    c = next(c for c in report["controls"] if c["sim"] == "pend-a")
    at = lambda what: "/" + loop_path("pend-a", what, c["model"], None)  # noqa: E731
    states = rows[at("state/states") + "/x"]
    assert len(states) == len(c["x"]) == 31
    assert [k for k, _ in states] == list(range(31))
    np.testing.assert_allclose(states[-1][1], c["x"][-1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(states[7][1], c["x"][7], rtol=0, atol=1e-12)
    assert len(rows[at("state/states") + "/reference"]) == 31
    assert len(rows[at("input")]) == len(c["u"]) == 30
    np.testing.assert_allclose(rows[at("input")][3][1], c["u"][3], atol=1e-12)
    assert len(rows[at("solve_us")]) == 30

    # The tracking task: each reference's loop per row (replay and the model), as many states
    # as the report says it ran.
    t = report["tracking"][0]
    assert t["sim"] == "pend-b" and t["references"] == 2
    for row in t["rows"]:
        for i, ran in enumerate(row["steps_run"]):
            path = "/" + loop_path("pend-b", "state/states", row["row"], i)
            assert len(rows[f"{path}/x"]) == ran + 1, (row["row"], i)
    # The trainer's progress: every job's loss terms and validation error.
    for job in report["train"]:
        assert len(rows[f"/train/{job['model']}/loss/total"]) >= 1, job["model"]
        assert len(rows[f"/train/{job['model']}/validation"]) >= 1, job["model"]
    assert len(rows["/run/collect/train"]) >= 1


def test_plan_strips_start_at_the_state_and_span_the_horizon(tmp_path):
    _, out = run(tmp_path, "--record-view")
    report = json.loads((out / "report.json").read_text())
    c = next(c for c in report["controls"] if c["sim"] == "pend-a")
    path = "/" + loop_path("pend-a", "plan/states", c["model"], None)
    strips = {}
    for ch in RrdReader(out / "view.rrd").stream():
        if ch.entity_path == path and not ch.is_static:
            b = ch.to_record_batch()
            col = next(n for n in b.schema.names if n.endswith(":strips"))
            strips.update(zip(b.column("step").to_pylist(), b.column(col).to_pylist(), strict=True))
    assert sorted(strips) == list(range(30))
    theta = np.array(strips[5][0])  # the first state's planned curve at step 5: (t, theta) pairs
    assert theta.shape == (11, 2)
    np.testing.assert_allclose(theta[:, 0], np.arange(11) * 0.02)  # seconds ahead (dt = 0.02 s)
    assert theta[0, 1] == pytest.approx(c["x"][5][0], abs=1e-5)


def test_a_viewer_that_cannot_start_is_a_warning_and_the_run_goes_on(tmp_path, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    r, out = run(tmp_path, "--view", "native")
    assert "the viewer could not start" in r.stderr, r.stderr
    assert "--view web" in r.stderr and "--record-view" in r.stderr and "needs a display" in r.stderr
    report = json.loads((out / "report.json").read_text())
    assert "view" not in report and report["controls"], report.keys()
    assert any("viewer could not start" in w for w in report["warnings"])


def test_a_corrupt_or_foreign_recording_gets_rerun_s_error_not_a_traceback(tmp_path):
    exe = koopbridge_binary_or_skip()
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(b"RRF2" + os.urandom(64))
    foreign = tmp_path / "notes.rrd"
    foreign.write_text("not a recording\n")
    for f in (bad, foreign, tmp_path / "missing.rrd"):
        r = subprocess.run([str(exe), "view", "--open", str(f)], env=scenario_env(exe), capture_output=True, text=True, timeout=60)
        assert r.returncode != 0
        assert str(f) in r.stderr and "Traceback" not in r.stderr and "panicked" not in r.stderr, r.stderr


def test_state_plots_follow_the_simulator_s_units_and_stay_readable():
    names = ["base_qw", "base_qx", "base_vx", "hip_q", "knee_q", "hip_qd", "knee_qd", "base_height"]
    units = ["1", "1", "m/s", "rad", "rad", "rad/s", "rad/s", "m"]
    groups = dict(state_groups(names, units))
    assert groups == {"unitless": [0, 1], "m_s": [2], "rad": [3, 4], "rad_s": [5, 6], "m": [7]}
    many = state_groups([f"x{i}" for i in range(30)])
    assert [len(i) for _, i in many] == [12, 12, 6] and sum((i for _, i in many), []) == list(range(30))
    assert state_groups(["a", "b"]) == [("states", [0, 1])]


GYM = idp_scenario("view-video", steps=40)


def test_video_renders_each_state_beside_its_reference(tmp_path):
    pytest.importorskip("gymnasium")
    iio = pytest.importorskip("imageio.v3")
    exe = koopbridge_binary_or_skip()
    sc = tmp_path / "view-video.toml"
    sc.write_text(GYM)
    out = tmp_path / "out"
    r = subprocess.run([str(exe), "run", str(sc), "--out", str(out), "--video", "0"], cwd=tmp_path, env=scenario_env(exe), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    c = report["control"]
    assert [Path(v).name for v in report["videos"]] == [f"cart-{c['model']}-ref000.mp4"]
    frames = iio.imread(report["videos"][0])
    # dt = 0.05 s at 25 frames per second: every state is a frame, the robot beside the reference.
    assert frames.shape == (len(c["x"]), 240, 640, 3), frames.shape
    left, right = frames[:, 40:200, :320].astype(float), frames[:, 40:200, 320:].astype(float)
    assert left.std() > 5 and right.std() > 5, "blank frames"

    def changed(a: np.ndarray, b: np.ndarray) -> float:
        """The share of pixels that changed visibly (a channel by more than 30 of 255)."""
        return float((np.abs(a - b).max(axis=-1) > 30).mean())

    # The reference (upright, still) is the same picture in every frame; the robot, tilted at
    # x0 (0.05 rad per pole), differs from it and moves (measured: 0.4 % and 0.5 % of pixels).
    assert changed(right[0], right[-1]) == 0.0
    assert changed(left[0], right[0]) > 0.001 and changed(left[0], left[-1]) > 0.001
    bad = subprocess.run([str(exe), "run", str(sc), "--out", str(out), "--video", "0,x"], env=scenario_env(exe), capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "'x'" in bad.stderr.replace('"', "'") and "reference index" in bad.stderr, bad.stderr
