"""The G1's survival task on the robot-agnostic legged code (issue 30): its references are
``g1_replay``'s, its replay floor through the real adapter (``--held locked``, over Zenoh) equals
the in-process replay and its score, bad models are refused with the G1's sizes, and the
scenario at CI's smoke budget runs data → train → track through the real MPC service with
finite survival figures beside the floor — as the Python driver (``g1_scenario``) and as
``scenarios/g1-survival.toml`` through ``koopbridge run``."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import uuid

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("onnxruntime")

from conftest import ROOT, Child, free_endpoint, koopbridge_binary_or_skip  # noqa: E402
from koopbridge.adapters import g1_model as g  # noqa: E402
from koopbridge.adapters.g1_sim import G1Simulator  # noqa: E402
from koopbridge.experiments import g1_replay, g1_survival, legged_survival  # noqa: E402
from koopbridge.experiments.go2_track import replay  # noqa: E402

try:
    g.model_file(), g.policy_file()
except g.ModelError as e:  # pragma: no cover - pinned in requirements.txt
    pytest.skip(str(e), allow_module_level=True)


def test_the_g1_command_line_defaults_to_the_23_dof_g1_at_0_10_rad():
    a = g1_survival.parser().parse_args(["--model", "m", "--out", "o"])
    assert (a.threshold, a.steps, a.held, a.expert) == (0.10, 200, "locked", "fastsac")
    assert g1_survival.ROBOT.adapter_args(a) == ["--held", "locked", "--expert", "fastsac"]
    assert (g1_survival.ROBOT.nx, g1_survival.ROBOT.nu) == (53, 23)


def test_references_and_the_replay_floor_through_the_adapter_equal_g1_replay(tmp_path, session_id):
    a = g1_survival.parser().parse_args(["--model", "m", "--out", "o"])
    refs = legged_survival.references(legged_survival.G1, 2, 40, a=a)
    # g1_replay's references: its own collection code, same seed, same simulator settings.
    sim, fresh = G1Simulator(held="locked", on_fall=None), G1Simulator(held="locked", memory=0, on_fall=None)
    want = g1_replay.make_references(sim, fresh, 2, 40)
    for r, w in zip(refs, want, strict=True):
        np.testing.assert_array_equal(r.x, w.x)
        np.testing.assert_array_equal(r.u, w.u)
    ep = free_endpoint()
    cmd = [sys.executable, "-m", "koopbridge.adapters.g1", "--session", session_id, "--id", "g1", "--connect", ep, "--quiet",
           "--held", "locked"]
    from koopbridge import Client

    with Child(cmd, tmp_path / "adapter.log") as adapter, Client(session=session_id, listen=[ep]) as c:
        info = c.connect_sim("g1", timeout=90)
        assert info["env"] == "unitree-g1-locked"
        fallen = legged_survival._fall_rule(legged_survival.G1, info)
        for r, w in zip(refs, want, strict=True):
            got = replay(c, "g1", r, fallen, threshold=0.10, layout=legged_survival.G1.layout)
            s, x = g1_replay.replay(fresh, w)
            np.testing.assert_allclose(got.x, x, rtol=0, atol=1e-12, err_msg=adapter.output())
            assert got.survival == s and 0 < s <= 40


def test_bad_input_a_missing_model_or_the_go2s_sizes(tmp_path, capsys):
    out = tmp_path / "out"
    assert g1_survival.main(["--model", str(tmp_path / "nope"), "--out", str(out)]) == 2
    assert "g1_survival: model folder" in capsys.readouterr().err
    assert g1_survival.main(["--model", str(tmp_path), "--out", str(out), "--threshold", "0"]) == 2
    koopbridge_binary_or_skip()
    from koopbridge import KoopmanModel

    KoopmanModel.init(35, 12, hidden=[8], n_mult=1).save(tmp_path / "go2ish")
    rc = g1_survival.main(["--model", str(tmp_path / "go2ish"), "--out", str(out), "--references", "1", "--steps", "3"])
    err = capsys.readouterr().err
    assert rc == 2 and "is 35/12-D (nx/nu, its config.json); the G1 is 53/23-D" in err, err


def test_the_g1_scenario_at_the_smoke_budget(tmp_path):
    """g1_scenario as CI runs it: collect (locked G1) → train (Koopman, normalised) → track 4
    references of 40 steps through the MPC service, the replay floor beside it."""
    koopbridge_binary_or_skip()
    from koopbridge.experiments import g1_scenario

    out = tmp_path / "run"
    assert g1_scenario.main(["--out", str(out)]) == 0
    s = json.loads((out / "scenario.json").read_text())
    assert s["budget"] == "smoke" and s["settings"]["steps"] == 40 and s["settings"]["references"] == 4
    meta = json.loads((out / "data" / "collect.json").read_text())
    assert "locked" in json.dumps(meta)
    (rnd,) = s["rounds"]
    rows = {r["controller"]: r for r in rnd["table"]}
    assert set(rows) == {"open-loop replay (floor)", "g1-both (koopman)"}
    for r in rows.values():
        assert r["n"] == 4 and np.isfinite(r["mean"]) and 0 <= r["min"] <= r["mean"] <= r["max"] <= 40, r
    assert rows["open-loop replay (floor)"]["mean"] >= 30  # the locked G1's replay follows (g1_replay: 198.6 of 200)
    assert np.isfinite(rows["g1-both (koopman)"]["test_pred"])
    rep = json.loads((out / "round0" / "track" / "report.json").read_text())
    assert rep["task"]["held"] == "locked" and "> 0.1 rad" in rep["task"]["metric"] and "53-D" in rep["task"]["start"]
    m = rep["models"]["g1-both"]
    assert m["normalised"] and sum(m["statuses"].values()) > 0 and len(m["survivals"]) == 4
    assert m["above_floor"] + m["below_floor"] <= 4
    for f in ("survival.png", "tracking.png", "tracking.mcap", "table.md"):
        assert (out / "round0" / "track" / f).stat().st_size > 0
    from mcap.reader import make_reader

    with open(out / "round0" / "track" / "tracking.mcap", "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert topics == {"/koopbridge/g1/state", "/koopbridge/g1/input", "/koopbridge/g1/reference"}


def test_the_g1_survival_toml_through_koopbridge_run(tmp_path):
    """scenarios/g1-survival.toml shrunk to a smoke budget: the locked G1's expert collects
    through the collect request, the trainer service trains, the hook writes references and the
    scenario engine tracks them (issue 47)."""
    exe = koopbridge_binary_or_skip()
    text = (ROOT / "scenarios" / "g1-survival.toml").read_text()
    for old, new in [("block = 250", "block = 40"), ("train_windows = 3000\n", "train_windows = 120\n"),
                     ("val_windows = 500\n", "val_windows = 40\n"), ("test_windows = 500\n", "test_windows = 40\n"),
                     ("iterations = 3000, n_mult = 4, hidden = [128, 128], validate_every = 500",
                      "iterations = 40, n_mult = 1, hidden = [32], validate_every = 20"),
                     ('"--references", "50", "--steps", "200"', '"--references", "2", "--steps", "40"')]:
        assert old in text, f"scenarios/g1-survival.toml has no {old!r}"
        text = text.replace(old, new)
    # Inside the repository, so that {python} is its venv, as for the shipped file.
    (ROOT / "target").mkdir(exist_ok=True)
    toml = ROOT / "target" / f"kb-py-g1-{uuid.uuid4().hex[:10]}.toml"
    toml.write_text(text)
    out = tmp_path / "run"
    try:
        r = subprocess.run([str(exe), "run", str(toml), "--out", str(out)], capture_output=True, text=True, timeout=600)
    finally:
        toml.unlink()
    assert r.returncode == 0, r.stderr[-3000:]
    rep = json.loads((out / "report.json").read_text())
    assert [t.get("label") for t in rep["tracking"]] == [None, "error-state", "push", "mass", "friction", "mass-friction"]
    spec, es = rep["tracking"][:2]
    rows = {row["row"]: row for task in (spec, es) for row in task["rows"]}
    assert set(rows) == {"replay", "g1-survival-g1", "g1-survival-g1+error-state"}
    # The perturbation suite: the G1's push is 0.5 m/s, each task with its own replay row.
    push = rep["tracking"][2]
    assert all(abs(np.hypot(*p["push"]["velocity"]) - 0.5) < 1e-9 for p in push["perturbations"])
    assert [r["row"] for r in push["rows"]] == ["replay", "g1-survival-g1+push"]
    for row in rows.values():
        s = row["survival"]
        assert s["n"] == 2 and np.isfinite(s["mean"]) and 0 <= s["min"] <= s["mean"] <= s["max"] <= 40, row
    assert spec["steps"] == 40 and spec["survival"]["threshold"] == 0.1
    # The recommended controller (docs/decisions/0017): Q on the 21 joint positions only, R = I.
    mpc = rows["g1-survival-g1+error-state"]["mpc"]
    assert [i for i, w in enumerate(mpc["q"]) if w > 0] == list(range(10, 31)) and mpc["r"] == [1.0] * 23
    assert (out / "tracking" / "table.md").stat().st_size > 0
    # The RL expert's row (the after-control hook): every survival task, its survivals finite
    # and within the references' length, beside the others in tracking/expert.md.
    expert = rep["expert"]["tasks"]
    assert [e["task"] for e in expert] == ["nominal", "error-state", "push", "mass", "friction", "mass-friction"]
    assert all(len(e["survivals"]) == 2 and all(0 <= v <= 40 for v in e["survivals"]) for e in expert), expert
    assert "| push |" in (out / "tracking" / "expert.md").read_text()
    assert json.loads((out / "report.json").read_text())["train"][0]["model"] == "g1-survival-g1"
    assert (out / "models" / "g1-survival-g1" / "config.json").is_file()
    shutil.rmtree(out, ignore_errors=True)
