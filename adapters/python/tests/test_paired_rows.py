"""paired_rows: the paired figures against the formulas written out, and its refusals."""

from __future__ import annotations

import json
import math

from koopbridge_experiments import paired_rows


def _report(path, rows):
    tasks = [dict(rows=[dict(row=name, survivals=s) for name, s in rows.items()])]
    path.write_text(json.dumps(dict(tracking=tasks)))
    return path


def test_pairs_are_compared_reference_by_reference(tmp_path, capsys):
    a0 = _report(tmp_path / "a0.json", {"m0+x": [10, 20, 30], "m0+y": [5, 5, 5]})
    b0 = _report(tmp_path / "b0.json", {"m0+x": [12, 20, 35], "m0+y": [5, 4, 9]})
    a1 = _report(tmp_path / "a1.json", {"n+x": [10, 10, 10], "n+y": [1, 1, 1]})
    b1 = _report(tmp_path / "b1.json", {"n+x": [9, 13, 10], "n+y": [1, 1, 2]})
    pairs = [(f"{a0}#m0+{{task}}", f"{b0}#m0+{{task}}"), (f"{a1}#n+{{task}}", f"{b1}#n+{{task}}")]
    x, y = paired_rows.compare(pairs, ["x", "y"])
    # Task x: differences [2, 0, 5] and [-1, 3, 0].
    d = [2, 0, 5, -1, 3, 0]
    mean = sum(d) / 6
    sem = math.sqrt(sum((v - mean) ** 2 for v in d) / 5) / math.sqrt(6)
    assert abs(x["diff"]["mean"] - mean) < 1e-3 and abs(x["diff"]["sem"] - sem) < 1e-3
    assert (x["pairs"][0]["better"], x["pairs"][0]["worse"]) == (2, 0)
    assert (x["pairs"][1]["better"], x["pairs"][1]["worse"]) == (1, 1)
    a_mean, b_mean = (20 + 10) / 2, ((12 + 20 + 35) / 3 + (9 + 13 + 10) / 3) / 2
    assert abs(x["gain_percent"] - 100 * (b_mean - a_mean) / a_mean) < 1e-9
    assert y["pairs"][0]["diff"]["mean"] == 1.0 and y["pairs"][1]["better"] == 1
    assert paired_rows.main(["--pair", *pairs[0], "--pair", *pairs[1], "--tasks", "x,y", "--names", "base,+both",
                             "--json", str(tmp_path / "g.json")]) == 0
    out = capsys.readouterr().out
    assert "| task | pairs | base | +both |" in out and "| x | 2 | 15.0 |" in out
    assert json.loads((tmp_path / "g.json").read_text())[0]["task"] == "x"


def test_an_aggregation_rounds_rows_pair_with_the_first_pass(tmp_path):
    tasks = [dict(rows=[dict(row="m+x", survivals=[1, 2, 3])])]
    rounds = [dict(round=1, tracking=[dict(rows=[dict(row="m-agg1+x", survivals=[2, 2, 5])])])]
    path = tmp_path / "r.json"
    path.write_text(json.dumps(dict(tracking=tasks, tracking_aggregation=rounds)))
    (x,) = paired_rows.compare([(f"{path}#m+x", f"{path}#m-agg1+x")], [""])
    assert x["pairs"][0]["diff"]["mean"] == 1.0 and (x["pairs"][0]["better"], x["pairs"][0]["worse"]) == (2, 0)


def test_a_missing_row_or_unequal_references_are_refused(tmp_path, capsys):
    a = _report(tmp_path / "a.json", {"r": [1, 2, 3]})
    b = _report(tmp_path / "b.json", {"r": [1, 2]})
    assert paired_rows.main(["--pair", f"{a}#r", f"{a}#nope"]) == 2
    err = capsys.readouterr().err
    assert "no tracking row 'nope'" in err and "(it has r)" in err
    assert paired_rows.main(["--pair", f"{a}#r", f"{b}#r"]) == 2
    assert "3 references" in capsys.readouterr().err
    assert paired_rows.main(["--pair", f"{tmp_path}/none.json#r", f"{a}#r"]) == 2
    assert paired_rows.main(["--pair", f"{a}", f"{a}#r"]) == 2
    assert "REPORT#ROW" in capsys.readouterr().err
