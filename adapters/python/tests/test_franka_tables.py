"""The Franka tables driver (``koopbridge_experiments.franka_tables``) end to end at a tiny
budget: it collects SPEC's data, trains every row through ``koopbridge sweep``/``train``, tracks
the figure-8 with every model in one ``koopbridge run`` per column (the NNDM by random shooting in
the MPC service), writes both tables, and a rerun finds every stage done."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import koopbridge_binary_or_skip

pytest.importorskip("mujoco")


def test_franka_tables_runs_every_stage_and_resumes(tmp_path, capsys):
    koopbridge_binary_or_skip()
    from koopbridge_experiments import franka_tables

    out = tmp_path / "ft"
    args = ["--out", str(out), "--windows", "600", "--table-samples", "400", "--samples", "200,400",
            "--iterations", "40", "--steps", "104", "--u-limit", "1.0", "--also-u-limits", "0.5"]
    assert franka_tables.main(args) == 0
    t = json.loads((out / "tables.json").read_text())
    rows = t["rows"]
    assert set(rows) == {"edmd", "nndm", "koopman-base", "koopman-ctrl", "koopman-cov", "koopman-both"}
    runs = {col: json.loads((out / col / "report.json").read_text()) for col in ("figure8", "figure8-clip0.5", "figure8-qd0.01")}
    for col, rep in runs.items():
        # One engine run per column: nothing collected or trained, every model a pretrained row.
        assert "collect" not in rep and rep["train"] == [] and {p["name"] for p in rep["pretrained"]} == set(rows), col
    controls = {col: {c["label"]: c for c in rep["controls"]} for col, rep in runs.items()}
    for name, r in rows.items():
        # Each row's prediction error is its model's own test metric, and its tracking error the
        # figure-8 report's (both written by other programs: the CLI and the scenario's hook).
        metrics = json.loads((Path(r["model"]) / "metrics.json").read_text())
        assert Path(r["model"]).is_relative_to(out) and r["prediction"] == metrics["test_prediction_error"], name
        assert r["tracking"] == runs["figure8"]["figure8"]["errors"][name] and np.isfinite(r["tracking"]), name
        row = controls["figure8"][name]
        assert row["model"] == name and row["observation_noise"] == {"sigma": 0.01, "states": [0, 1, 2], "seed": 0}
        assert r["solve_median_us"] == row["solve_median_us"] > 0
        assert len(row["u"]) == 103 and np.max(np.abs(row["u"])) <= 1.0 + 1e-9
        # The other columns: the same model at the other clip and with q̇ weighted 0.01, own runs.
        clip, qd = controls["figure8-clip0.5"][name], controls["figure8-qd0.01"][name]
        assert clip["mpc"]["u_max"] == [0.5] * 7 and np.max(np.abs(clip["u"])) <= 0.5 + 1e-9
        assert qd["mpc"]["u_max"] == [1.0] * 7 and qd["mpc"]["q"] == [1.0] * 10 + [0.01] * 7
        assert r["tracking_also"] == {"clip ±0.5 rad/s": runs["figure8-clip0.5"]["figure8"]["errors"][name],
                                      "q̇ weight 0.01": runs["figure8-qd0.01"]["figure8"]["errors"][name]}, name
    base = rows["koopman-base"]["tracking"]
    assert rows["koopman-both"]["gain_over_base"] == pytest.approx((base - rows["koopman-both"]["tracking"]) / base)
    # The +both m-sweep (m = 200 and 400) gave a curve to fit.
    assert [c for c in t["scaling"]["curves"] if "both" in c["label"]][0]["points"]
    both = {"zero-input", "joint-follower"}
    assert set(t["baselines"]) == both and all(set(b) == both for b in t["baselines_also"].values())
    assert "| nndm |" in (out / "tables.md").read_text()
    capsys.readouterr()
    # A rerun runs nothing but the refit: every other stage is found done.
    assert franka_tables.main(args) == 0
    printed = capsys.readouterr().out
    assert printed.count(": done") == 8 and "done in" in printed, printed
