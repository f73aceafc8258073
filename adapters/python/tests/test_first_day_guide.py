"""docs/your-own-simulator.md, run as written: its ``sh`` blocks in order in one bash shell, in an
empty folder outside the repository, with each block marked ``<!-- file: NAME -->`` written to
NAME where it stands. Then what the guide says its commands do is checked: the three simulators
pass check_adapter, both runs train a Koopman and an EDMD model and control with each (the rerun
reusing the data and the EDMD model, its Koopman model predicting and controlling better), the
in-process loop gives the scenario's result, the EDMD model of the command line is written."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gymnasium")
pytest.importorskip("mujoco")
pytest.importorskip("fmpy")

from conftest import ROOT, koopbridge_binary_or_skip  # noqa: E402

GUIDE = ROOT / "docs" / "your-own-simulator.md"
FENCE = re.compile(r"(?:<!-- file: (?P<name>[\w.-]+) -->\n)?```(?P<lang>\w*)\n(?P<body>.*?)^```$", re.M | re.S)


def guide_script(text: str) -> tuple[str, list[str]]:
    """The bash script the guide's blocks make (files as quoted here-documents, ``sh`` blocks as
    they are), and the names of the files it writes."""
    parts, files = ["set -euo pipefail"], []
    for m in FENCE.finditer(text):
        name, lang, body = m.group("name"), m.group("lang"), m.group("body")
        if name:
            assert "KOOPBRIDGE_GUIDE_EOF" not in body
            parts.append(f"cat > {name} <<'KOOPBRIDGE_GUIDE_EOF'\n{body}KOOPBRIDGE_GUIDE_EOF")
            files.append(name)
        elif lang == "sh":
            parts.append(f"echo '+ guide block {len(parts)}'\n{body}")
    return "\n".join(parts) + "\n", files


def test_the_guide_blocks_are_found():
    script, files = guide_script(GUIDE.read_text())
    assert files == ["mysim.py", "check.py", "pendulum.toml", "control.py", "summary.py"]
    for needle in (
        "python mysim.py --describe",
        "koopbridge.adapters.fmu",
        "koopbridge.adapters.gym Reacher-v5",
        "python check.py",
        "koopbridge run pendulum.toml",
        "--model edmd",
        "koopbridge eval",
        'model = ["koopman", "edmd"]',
        "python control.py results/pend/models/my-pendulum-pend",
        "python summary.py",
    ):
        assert needle in script, needle
    assert script.count("koopbridge run pendulum.toml") == 2


def test_every_command_of_the_guide_runs(tmp_path, damped_fmu):
    exe = koopbridge_binary_or_skip()
    script, _ = guide_script(GUIDE.read_text())
    (tmp_path / "guide.sh").write_text(script)
    env = {k: v for k, v in os.environ.items() if k != "KOOPBRIDGE_PYTHON"}
    env["KOOPBRIDGE_REPO"] = str(ROOT)
    env["PATH"] = os.pathsep.join([str(exe.parent), str(Path(sys.executable).parent), env.get("PATH", "")])
    if not any((d / ".venv" / "bin" / "python").is_file() for d in exe.resolve().parents):
        env["KOOPBRIDGE_PYTHON"] = sys.executable  # a binary installed elsewhere: name the Python
    r = subprocess.run(["bash", "guide.sh"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=240)
    log = r.stdout[-4000:] + "\n--- stderr ---\n" + r.stderr[-4000:]
    assert r.returncode == 0, log

    for env_name in ("my-pendulum", "damped_pendulum", "Reacher-v5"):
        assert re.search(rf"^{re.escape(env_name)}\S*: ok \(", r.stdout, re.M), log
    assert "reusing the data collected before" in r.stderr, log
    assert (tmp_path / "models" / "pend-edmd" / "metrics.json").is_file()
    koopman_line = re.search(r"^results/pend/models/my-pendulum-pend: final state .*, error ([\d.]+)$", r.stdout, re.M)
    assert koopman_line, log

    # The summaries of both runs: the rerun (5,000 iterations) predicts and controls better.
    summaries = re.findall(r"^pend with my-pendulum-pend: final state .* final error ([\d.]+), time to goal (\w+)", r.stdout, re.M)
    errors = re.findall(r"^model my-pendulum-pend: test prediction error ([\d.]+)$", r.stdout, re.M)
    assert len(summaries) == 2 and len(errors) == 2, log
    first, second = (float(e) for e, _ in summaries)
    # The in-process loop of §5 on the first model gives the scenario's own result.
    assert float(koopman_line.group(1)) == pytest.approx(first, abs=1e-4)
    assert float(errors[1]) < float(errors[0]) and second < first, (errors, summaries)
    report = json.loads((tmp_path / "results" / "pend" / "report.json").read_text())
    c = report["control"]
    assert np.all(np.isfinite(c["x"])) and c["final_error"] == pytest.approx(second, abs=1e-4)
    assert report["train"][0]["metrics"]["config"]["iterations"] == 5000
    # Two kinds side by side; the EDMD model (no iterations) reused by the rerun.
    assert [m["kind"] for m in report["models"]] == ["koopman", "edmd"], report["models"]
    assert "reusing model 'my-pendulum-pend-edmd'" in r.stderr, log
    assert len(re.findall(r"^pend with my-pendulum-pend-edmd: final state", r.stdout, re.M)) == 2, log
