"""The G1's survival task (issue 30): its references (``legged_robots.references``) are
``g1_replay``'s, the real adapter (``--held locked``, over Zenoh) replays them as ``g1_replay``
does in-process, with the same score, and ``scenarios/g1-survival.toml`` at CI's smoke budget runs
data → train → track through ``koopbridge run`` with finite survival figures beside the floor."""

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
from koopbridge import survival  # noqa: E402
from koopbridge.adapters.legged.g1 import model as g  # noqa: E402
from koopbridge.adapters.legged.g1.sim import G1Simulator  # noqa: E402
from koopbridge_experiments import g1_replay, legged_robots  # noqa: E402

try:
    g.model_file(), g.policy_file()
except g.ModelError as e:  # pragma: no cover - pinned in requirements.txt
    pytest.skip(str(e), allow_module_level=True)


def test_references_and_the_replay_floor_through_the_adapter_equal_g1_replay(tmp_path, session_id):
    refs = legged_robots.references(legged_robots.G1, 2, 40)  # the defaults: --held locked, --expert fastsac
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

    lay = legged_robots.G1.layout
    with Child(cmd, tmp_path / "adapter.log") as adapter, Client(session=session_id, listen=[ep]) as c:
        info = c.connect_sim("g1", timeout=90)
        assert info["env"] == "unitree-g1-locked"
        for r in refs:
            s, x = g1_replay.replay(fresh, g1_replay.G1Reference(x=r.x, u=r.u, index=r.index))
            # The recorded targets through the adapter, as far as the in-process replay went (to its end or a fall).
            got = np.array([c.reset("g1", x0=r.x[0])] + [c.step("g1", u)[2] for u in r.u[: len(x) - 1]])
            np.testing.assert_allclose(got, x, rtol=0, atol=1e-12, err_msg=adapter.output())
            joints = list(range(lay.q.start, lay.q.stop))
            assert survival(got, r.x, g1_replay.fallen_mask(got).tolist(), 0.10, joints, r.steps) == s and 0 < s <= 40


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
