"""The Franka tables driver (``koopbridge_experiments.franka_tables``) end to end at a tiny
budget: it collects SPEC's data, trains every row through ``koopbridge sweep``/``train``, tracks
the figure-8 through the bridge with each model (the NNDM by random shooting in the MPC service),
writes both tables, and a rerun finds every stage done."""

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
    for name, r in rows.items():
        # Each row's prediction error is its model's own test metric, and its tracking error the
        # figure-8 report's (both written by other programs: the CLI and figure8.py).
        metrics = json.loads((Path(r["model"]) / "metrics.json").read_text())
        assert Path(r["model"]).is_relative_to(out) and r["prediction"] == metrics["test_prediction_error"], name
        fig8 = json.loads((out / "figure8" / name / "report.json").read_text())
        assert r["tracking"] == fig8["controllers"]["mpc"]["error"] and np.isfinite(r["tracking"]), name
        assert fig8["model"]["name"] == Path(r["model"]).name
        # The other columns: the same model at the other clip and with q̇ weighted 0.01, own runs.
        clip = json.loads((out / "figure8-clip0.5" / name / "report.json").read_text())
        qd = json.loads((out / "figure8-qd0.01" / name / "report.json").read_text())
        assert clip["task"]["u_limit"] == 0.5 and qd["task"]["u_limit"] == 1.0 and qd["task"]["q"] == [1.0] * 10 + [0.01] * 7
        assert r["tracking_also"] == {"clip ±0.5 rad/s": clip["controllers"]["mpc"]["error"],
                                      "q̇ weight 0.01": qd["controllers"]["mpc"]["error"]}, name
    base = rows["koopman-base"]["tracking"]
    assert rows["koopman-both"]["gain_over_base"] == pytest.approx((base - rows["koopman-both"]["tracking"]) / base)
    # The +both m-sweep (m = 200 and 400) gave a curve to fit.
    assert [c for c in t["scaling"]["curves"] if "both" in c["label"]][0]["points"]
    assert set(t["baselines"]) == {"zero", "p"} and all(set(b) == {"zero", "p"} for b in t["baselines_also"].values())
    assert "| nndm |" in (out / "tables.md").read_text()
    capsys.readouterr()
    # A rerun runs nothing but the refit: every other stage is found done.
    assert franka_tables.main(args) == 0
    printed = capsys.readouterr().out
    assert printed.count(": done") == 23 and "done in" in printed, printed
