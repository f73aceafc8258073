"""The Go2 tracking task (issue 25 §3): the survival metric against hand computations (an error
crossing 0.16 rad at a known step, falls by height and by tilt, the cap), the open-loop replay
floor through a real adapter against the same replay computed in-process, the on-policy windows
and their union with the expert data, bad input (a missing model folder, a model of the wrong
nx), and the whole pipeline (collect → train → track → aggregate) on a tiny model."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from conftest import Child, free_endpoint, koopbridge_binary_or_skip
from koopbridge.adapters.go2_model import FALL
from koopbridge.experiments import go2_survival, go2_union
from koopbridge.experiments.go2_track import (
    Rollout,
    fallen_mask,
    joint_errors,
    make_references,
    reference_window,
    replay,
    rollout_windows,
    survival,
)

L = 10


def _standing(n: int) -> np.ndarray:
    """``n`` upright states: quaternion (1, 0, 0, 0), joints 0, base height 0.3 m."""
    x = np.zeros((n, 35))
    x[:, 0] = 1.0
    x[:, 34] = 0.3
    return x


def _score(x: np.ndarray, ref: np.ndarray, length: int = L) -> int:
    return survival(joint_errors(x, ref), fallen_mask(x, FALL.fallen), length)


def test_survival_counts_the_steps_before_the_error_first_exceeds_the_threshold():
    ref = _standing(L + 1)
    ref[:, 10:22] = np.linspace(-0.5, 0.5, 12)  # any reference: only the difference counts
    x = ref.copy()
    # One joint off by 12 * 0.05 k: the mean over the 12 joints is 0.05 k (0.15 at k = 3, 0.20 at k = 4).
    x[:, 13] += 12 * 0.05 * np.arange(L + 1)
    np.testing.assert_allclose(joint_errors(x, ref), 0.05 * np.arange(L + 1), atol=1e-12)
    assert _score(x, ref) == 3
    # Exactly at the threshold is no failure; just above is (0.125: exact in binary floating point).
    flat = _standing(L + 1)
    y = flat.copy()
    y[5:, 10:22] += 0.125
    errors, fell = joint_errors(y, flat), fallen_mask(y, FALL.fallen)
    assert survival(errors, fell, L, threshold=0.125) == L
    y[7, 10:22] += 1e-6
    assert survival(joint_errors(y, flat), fell, L, threshold=0.125) == 6
    # The error may come back below the threshold: the first crossing counts.
    z = ref.copy()
    z[2, 10:22] += 0.3
    assert _score(z, ref) == 1
    # A run that ends at its failure scores the same as the whole run.
    assert _score(x[:5], ref) == 3


def test_a_fall_ends_survival_by_height_or_tilt_and_the_cap_holds():
    ref = _standing(L + 1)
    x = ref.copy()
    x[4, 34] = FALL.min_height - 0.01
    assert _score(x, ref) == 3
    tilted = ref.copy()
    a = FALL.max_tilt + 0.05  # rolled about the body's x axis
    tilted[6, 0:4] = [np.cos(a / 2), np.sin(a / 2), 0.0, 0.0]
    assert fallen_mask(tilted, FALL.fallen).tolist() == [k == 6 for k in range(L + 1)]
    assert _score(tilted, ref) == 5
    assert _score(ref, ref) == L  # perfect tracking: the reference length
    assert _score(ref[:4], ref, length=3) == 3
    nan = ref.copy()
    nan[2] = np.nan  # a simulator failure reads as a failure at that step
    assert _score(nan, ref) == 1
    with pytest.raises(ValueError, match="cannot be scored"):
        _score(ref[:5], ref)


def test_reference_windows_and_on_policy_windows():
    ref = np.arange(6.0)[:, None] * np.ones((1, 35))
    np.testing.assert_array_equal(reference_window(ref, 3, 4)[:, 0], [4, 5, 5, 5])
    x = _standing(38)
    x[:, 20] = np.arange(38)
    u = np.arange(37.0)[:, None] * np.ones((1, 12))
    fell = x.copy()
    fell[33, 34] = 0.05  # a fall at state 33: transitions up to 32 -> 33 are excluded
    wx, wu = rollout_windows([Rollout(x=x, u=u, survival=37), Rollout(x=fell, u=u, survival=32)], 15, FALL.fallen)
    # 37 transitions -> 2 windows; 32 good transitions -> 2 windows.
    assert wx.shape == (4, 16, 35) and wu.shape == (4, 15, 12)
    np.testing.assert_array_equal(wx[1, :, 20], np.arange(15, 31))
    np.testing.assert_array_equal(wu[1, :, 0], np.arange(15, 30))
    assert not fallen_mask(wx.reshape(-1, 35), FALL.fallen).any()


def test_q_zscore_is_identity_on_the_models_normalised_state(tmp_path):
    std = np.linspace(0.5, 4.0, 35)
    m = go2_survival.ModelEntry(tmp_path, "m", {"kind": "koopman", "normalisation": {"x_std": std.tolist()}})
    raw = go2_survival.ModelEntry(tmp_path, "e", {"kind": "edmd", "normalisation": None})
    q, source = go2_survival.q_weights("zscore", [raw, m], 35)
    # (x - r)^T diag(q) (x - r) = |(x - r) / std|^2: Q = I on the z-scored state.
    d = np.arange(35.0)
    assert np.isclose(d @ (np.asarray(q) * d), np.sum((d / std) ** 2)) and "m's normalisation" in source
    assert go2_survival.q_weights("1," * 34 + "2", [], 35)[0][-1] == 2.0


def test_q_joints_keeps_the_zscore_weights_of_the_joint_positions_only(tmp_path):
    std = np.linspace(0.5, 4.0, 35)
    m = go2_survival.ModelEntry(tmp_path, "m", {"kind": "koopman", "normalisation": {"x_std": std.tolist()}})
    q, source = go2_survival.q_weights("joints", [m], 35, joints=slice(10, 22))
    want = np.where((np.arange(35) >= 10) & (np.arange(35) < 22), 1.0 / std**2, 0.0)
    np.testing.assert_allclose(q, want)
    assert source.startswith("joints") and "10..21" in source
    with pytest.raises(go2_survival.SetupError, match="names no joint"):
        go2_survival.q_weights("joints", [m], 35)


def test_the_scenario_driver_refuses_a_negative_noise(tmp_path, capsys):
    from koopbridge.experiments import go2_scenario

    assert go2_scenario.main(["--out", str(tmp_path / "o"), "--noise", "-0.1"]) == 2
    assert "--noise must be a finite number >= 0" in capsys.readouterr().err


def test_a_negative_or_nan_error_state_r_exits_2(tmp_path, capsys):
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "config.json").write_text('{"kind": "koopman"}')
    for bad in ("-1", "nan"):
        assert go2_survival.main(["--model", str(tmp_path / "m"), "--error-state-r", bad, "--out", str(tmp_path / "o")]) == 2
        assert "--error-state-r must be finite" in capsys.readouterr().err


def test_the_replay_floor_through_the_adapter_equals_the_replay_in_process(tmp_path, session_id):
    from koopbridge import Client
    from koopbridge.adapters.go2_sim import Go2Simulator

    refs = make_references(2, 25, seed=7)
    # The sim that collected the references restores their starts exactly: replay is the reference.
    home = Go2Simulator()
    make_references(2, 25, seed=7, sim=home)
    x = [home.reset(x0=refs[1].x[0])] + [home.step(u) for u in refs[1].u]
    np.testing.assert_array_equal(np.array(x), refs[1].x)
    # A fresh simulator starts from the 35-D state alone: the replay drifts, as the adapter's does.
    fresh = Go2Simulator()
    ep = free_endpoint()
    cmd = [sys.executable, "-m", "koopbridge.adapters.go2", "--session", session_id, "--id", "g", "--connect", ep, "--quiet"]
    with Child(cmd, tmp_path / "adapter.log") as adapter, Client(session=session_id, listen=[ep]) as c:
        c.connect_sim("g", timeout=60)
        for r in refs:
            got = replay(c, "g", r, FALL.fallen)
            xs = [fresh.reset(x0=r.x[0])] + [fresh.step(u) for u in r.u]
            want = np.array(xs)
            np.testing.assert_allclose(got.x, want, rtol=0, atol=1e-12, err_msg=adapter.output())
            assert got.survival == _score(want, r.x, r.steps)
            assert 0 < np.max(joint_errors(want, r.x)) and got.u.shape == r.u.shape


def test_bad_input_a_missing_model_or_a_wrong_nx(tmp_path, capsys):
    out = tmp_path / "out"
    assert go2_survival.main(["--model", str(tmp_path / "nope"), "--out", str(out)]) == 2
    assert "nope does not exist" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert go2_survival.main(["--model", str(tmp_path / "empty"), "--out", str(out)]) == 2
    assert "no config.json" in capsys.readouterr().err
    with pytest.raises(go2_survival.SetupError, match="35 finite"):
        go2_survival.q_weights("1,2", [], 35)
    assert go2_survival.q_weights("identity", [], 35)[0] is None
    koopbridge_binary_or_skip()
    from koopbridge import KoopmanModel

    KoopmanModel.init(2, 1, hidden=[8], n_mult=1).save(tmp_path / "pendulum")
    rc = go2_survival.main(["--model", str(tmp_path / "pendulum"), "--out", str(out), "--references", "1", "--steps", "3"])
    err = capsys.readouterr().err
    assert rc == 2 and "is 2/1-D (nx/nu, its config.json); the Go2 is 35/12-D" in err, err


def test_the_pipeline_on_a_tiny_model(tmp_path):
    """go2_scenario at a tiny budget: collect → train (Koopman normalised, EDMD, NNDM) → track
    through the bridge → aggregate the Koopman MPC's closed loops → retrain → track again."""
    exe = koopbridge_binary_or_skip()
    from koopbridge.experiments import go2_scenario

    out = tmp_path / "run"
    rc = go2_scenario.main(["--out", str(out), "--models", "both,edmd,nndm", "--aggregate", "1", "--references", "3", "--steps", "30",
                            "--noise", "0.1"])
    assert rc == 0
    # The expert collected with noise on its targets (--noise, recorded in the data's metadata).
    assert "expert+noise" in json.loads((out / "data" / "collect.json").read_text())["policy"]["kind"]
    s = json.loads((out / "scenario.json").read_text())
    assert [r["round"] for r in s["rounds"]] == [0, 1]
    for rnd in s["rounds"]:
        rows = {r["controller"]: r for r in rnd["table"]}
        assert set(rows) == {"open-loop replay (floor)", "go2-both (koopman)", "go2-edmd (edmd)", "go2-nndm (nndm)"}
        for r in rows.values():
            assert r["n"] == 3 and np.isfinite(r["mean"]) and 0 <= r["min"] <= r["mean"] <= r["max"] <= 30, r
        rep = json.loads((out / f"round{rnd['round']}" / "track" / "report.json").read_text())
        for m in rep["models"].values():
            assert len(m["survivals"]) == 3 and all(0 <= v <= 30 for v in m["survivals"])
            assert sum(m["statuses"].values()) > 0
        assert rep["models"]["go2-both"]["normalised"] and not rep["models"]["go2-edmd"]["normalised"]
        for f in ("survival.png", "tracking.png", "tracking.mcap", "table.md"):
            assert (out / f"round{rnd['round']}" / "track" / f).stat().st_size > 0
    # Round 1 trained on the expert windows plus round 0's on-policy ones.
    agg = s["rounds"][0]["aggregated"]
    x0, _, _ = go2_union.load_dataset_npz(out / "data" / "train.npz")
    x1, u1, meta = go2_union.load_dataset_npz(out / "round1" / "data" / "train.npz")
    assert agg["windows"] > 0 and len(x1) == len(x0) + agg["windows"] == agg["union_train"]
    np.testing.assert_array_equal(x1[: len(x0)], x0)
    assert u1.shape == (len(x1), 15, 12) and "on-policy" in meta["policy"]
    # The MCAP holds the recorder's three channels, Foxglove's JSON + jsonschema.
    import jsonschema
    from mcap.reader import make_reader

    with open(out / "round0" / "track" / "tracking.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        msgs: dict[str, list[dict]] = {c.topic: [] for c in summary.channels.values()}
        for schema, channel, message in reader.iter_messages():
            m = json.loads(message.data)
            jsonschema.validate(m, json.loads(schema.data))
            msgs[channel.topic].append(m)
    assert set(msgs) == {"/koopbridge/go2/state", "/koopbridge/go2/input", "/koopbridge/go2/reference"}
    states, inputs, refs = (msgs[f"/koopbridge/go2/{k}"] for k in ("state", "input", "reference"))
    assert len(states) == len(refs) == len(inputs) + 1 > 1
    np.testing.assert_allclose(states[0]["x"], refs[0]["x_ref"], atol=1e-9)  # the run starts at the reference's first state
    assert states[1]["state"]["base_height"] == states[1]["x"][34]
    assert exe.exists()
