"""The issue 26 §4 tools: ``franka_coverage`` measured against a per-sample, per-joint brute-force
count on a written dataset (and on the real figure-8 reference with data drawn around it), and
``franka_regulariser`` variants of the shipped figure-8 scenario read back as TOML with exactly
the row's training settings and MPC weighting, and its table over written reports."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from koopbridge_experiments import franka_coverage, franka_regulariser
from koopbridge_experiments.dataset_npz import DatasetMeta, save_dataset_npz

ROOT = Path(__file__).resolve().parents[3]
NAMES = ["ee_x", "ee_y", "ee_z"] + [f"q{i}" for i in range(1, 8)] + [f"qd{i}" for i in range(1, 8)]


def _dataset(path: Path, x: np.ndarray, names: list[str]) -> None:
    meta = DatasetMeta(env="franka-panda", dt=0.02, state_names=names, input_names=[f"u{i}" for i in range(7)],
                       seed=1, source="test", policy="uniform")
    save_dataset_npz(str(path / "train.npz"), x, np.zeros((x.shape[0], x.shape[1] - 1, 7)), meta)


def test_coverage_matches_a_brute_force_count(tmp_path, capsys):
    rng = np.random.default_rng(3)
    x = rng.uniform(-1.0, 1.0, size=(40, 6, 17))
    # Permute the joints' columns so that only the names can find them.
    names = NAMES[:]
    names[3], names[9] = names[9], names[3]
    _dataset(tmp_path, x, names)
    ref = rng.uniform(-1.3, 1.3, size=(500, 17))
    np.save(tmp_path / "ref.npy", ref)
    assert franka_coverage.main(["--data", str(tmp_path), "--reference", str(tmp_path / "ref.npy"), "--json", str(tmp_path / "c.json")]) == 0
    c = json.loads((tmp_path / "c.json").read_text())[str(tmp_path)]
    cols = [9, 4, 5, 6, 7, 8, 3]  # q1 sits at column 9, q7 at column 3
    states = x.reshape(-1, 17)
    inside_all = np.ones(len(ref), dtype=bool)
    for j, col in enumerate(cols):
        lo, hi = min(s[col] for s in states), max(s[col] for s in states)
        assert c["data_min"][j] == lo and c["data_max"][j] == hi
        inside = np.array([lo <= v <= hi for v in ref[:, col]])
        assert c["fraction_inside_per_joint"][j] == pytest.approx(inside.mean())
        inside_all &= inside
        assert c["max_outside_rad"][j] == pytest.approx(max(0.0, lo - ref[:, col].min(), ref[:, col].max() - hi))
    assert c["fraction_inside_box"] == pytest.approx(inside_all.mean())
    assert 0.0 < c["fraction_inside_box"] < 1.0
    nn = [min(np.linalg.norm(r[cols] - s[cols]) for s in states) for r in ref]
    assert c["nearest_data_rad_median"] == pytest.approx(float(np.median(nn)), abs=1e-9)
    assert c["nearest_data_rad_max"] == pytest.approx(max(nn), abs=1e-9)
    assert "joint-wise box" in capsys.readouterr().out


def test_coverage_of_the_figure8_reference_by_data_around_it(tmp_path):
    pytest.importorskip("mujoco")
    from koopbridge_experiments import figure8_scenario

    ref_path = tmp_path / "ref.npy"
    assert figure8_scenario.main(["reference", "--u-limit", "1.0", "--steps", "301", "--out", str(ref_path)]) == 0
    ref = np.load(ref_path)
    q = ref[:, 3:10]
    home = q.mean(axis=0)
    # Data half as wide as the path around its centre: the middle is covered, the ends are not.
    half = 0.5 * (q.max(axis=0) - q.min(axis=0)) / 2
    x = np.tile(ref[:1], (2, 2, 1))
    x[0, :, 3:10], x[1, :, 3:10] = home - half, home + half
    _dataset(tmp_path, x, NAMES)
    states, names = franka_coverage.load_states(tmp_path)
    c = franka_coverage.coverage(states, ref, franka_coverage.joint_columns(names, 17))
    moving = np.ptp(q, axis=0) > 0
    assert all(0.0 < f < 1.0 for f, m in zip(c["fraction_inside_per_joint"], moving, strict=True) if m)
    assert c["fraction_inside_box"] <= min(c["fraction_inside_per_joint"])


def test_bad_inputs_are_explained(tmp_path, capsys):
    np.save(tmp_path / "ref.npy", np.zeros((3, 5)))
    assert franka_coverage.main(["--data", str(tmp_path / "none"), "--reference", str(tmp_path / "ref.npy")]) == 2
    assert "not a dataset file" in capsys.readouterr().err
    _dataset(tmp_path, np.zeros((2, 3, 17)), NAMES)
    assert franka_coverage.main(["--data", str(tmp_path), "--reference", str(tmp_path / "ref.npy")]) == 2
    assert "differ in width" in capsys.readouterr().err
    with pytest.raises(ValueError, match="unknown row"):
        franka_regulariser.variant("", "huge", 1, "spec")
    with pytest.raises(ValueError, match="no longer has"):
        franka_regulariser.variant("name = 'x'\n", "base", 1, "spec")


@pytest.mark.parametrize("row", list(franka_regulariser.ROWS))
@pytest.mark.parametrize("q", list(franka_regulariser.QS))
def test_variant_of_the_shipped_scenario(row, q):
    text = (ROOT / "scenarios" / "franka-figure8.toml").read_text()
    orig = tomllib.loads(text)
    v = tomllib.loads(franka_regulariser.variant(text, row, 17383, q))
    kind = franka_regulariser.ROWS[row][0]
    assert v["train"]["model"] == [kind]
    cfg = v["train"]["config"]
    if kind == "edmd":
        assert cfg == {} and "train_config" not in v["full"]  # EDMD refuses iterations, also in [full]
    else:
        assert cfg["seed"] == 17383 and cfg["iterations"] == orig["train"]["config"]["iterations"]
        want = {"base": (False, False), "cov": (False, True), "ctrl": (True, False), "both": (True, True)}.get(row)
        assert (cfg.get("ctrl"), cfg.get("cov")) == (want if want else (None, None))
    rows = {c["label"]: c for c in v["control"]}
    orig_rows = {c["label"]: c for c in orig["control"]}
    assert ("q" in rows["koopman-mpc"]["mpc"]) == (q == "qd001")
    if q == "qd001":
        assert rows["koopman-mpc"]["mpc"] == orig_rows["koopman-mpc"]["mpc"]
    assert v["collect"] == orig["collect"] and v["sims"] == orig["sims"]  # the same data for every row
    # The error-state rows are not the table's; the baselines stay as they were.
    assert {k for k in orig_rows if k.startswith("error-state")} == {"error-state-mpc", "error-state-mpc-position-loop"}
    assert set(rows) == {"koopman-mpc", "zero-input", "joint-follower"}
    assert all(rows[k] == orig_rows[k] for k in ("zero-input", "joint-follower"))
    assert v["hooks"] == orig["hooks"] and v["control_defaults"] == orig["control_defaults"]


def test_table_means_and_relative_change(tmp_path):
    for row, seed, q, e in [("base", 1, "spec", 10.0), ("base", 2, "spec", 12.0), ("both", 1, "spec", 8.0), ("both", 2, "spec", 9.0),
                            ("base", 1, "qd001", 2.0), ("junk", 1, "spec", 1.0)]:
        d = tmp_path / f"{row}-s{seed}-{q}"
        d.mkdir()
        (d / "report.json").write_text(json.dumps({"figure8": {"errors": {"koopman-mpc": e, "zero-input": 12.5, "joint-follower": 0.003}}}))
    md, raw = franka_regulariser.table(tmp_path)
    assert raw["errors"]["both"]["spec"] == {1: 8.0, 2: 9.0}
    both = next(line for line in md.splitlines() if line.startswith("| both |"))
    assert "8.500 ± 0.707 (n=2)" in both and f"{100 * (8.5 / 11 - 1):+.1f} %" in both
    assert "| base | — | 11.000 ± 1.414 (n=2) | 2.000 |" in md


def test_variant_with_a_budget_changes_only_the_data_size_and_iterations():
    text = (ROOT / "scenarios" / "franka-figure8.toml").read_text()
    orig = tomllib.loads(text)
    v = tomllib.loads(franka_regulariser.variant(text, "both", 17382, "spec", windows=20000, iterations=10000))
    assert (v["collect"]["train_windows"], v["collect"]["val_windows"], v["collect"]["test_windows"]) == (20000, 2000, 2000)
    assert v["train"]["config"]["iterations"] == 10000
    assert v["full"] == orig["full"]  # --full keeps SPEC's budget
    rest = {k: x for k, x in v["collect"].items() if not k.endswith("_windows")}
    assert rest == {k: x for k, x in orig["collect"].items() if not k.endswith("_windows")}
    e = tomllib.loads(franka_regulariser.variant(text, "edmd", 17382, "spec", windows=20000, iterations=10000))
    assert e["train"]["config"] == {} and e["collect"]["train_windows"] == 20000
    with pytest.raises(ValueError, match="positive"):
        franka_regulariser.variant(text, "base", 1, "spec", windows=0)
