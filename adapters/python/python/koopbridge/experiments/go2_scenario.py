"""The Go2 survival scenario end to end (issue 25 §3): collect expert data (``go2_data``) → train
(``koopbridge train --normalise --gamma 0.99``; EDMD and NNDM on raw units) → track held-out
references through the bridge (``go2_survival``) → report; with ``--aggregate R``, R rounds of
on-policy aggregation (the first model's closed loops on references of their own, never the
held-out ones, join the training data, ``go2_union``; every model is retrained on the union and
tracks the held-out references again). The default budget is CI's (about a
minute); ``--full`` is the paper's (SPEC: 180k windows, 20k iterations, n_mult 16, 50
references, the six models).

    python -m koopbridge.experiments.go2_scenario --out OUT [--full] [--data DIR] [--models both,edmd] [--aggregate 1]

Writes ``OUT/scenario.json`` (every round's survival table with the models' test L_pred),
``OUT/data`` (unless ``--data``), ``OUT/round{r}/models/{name}``, ``OUT/round{r}/track``
(``go2_survival``'s report, figures and MCAP), ``OUT/round{r}/aggregate`` (the closed loops aggregated after
round r) and ``OUT/round{r}/data`` (the union, r ≥ 1).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .dataset_npz import write_atomic
from .figure8 import koopbridge_cli

__all__ = ["AGGREGATION_SEED", "BUDGETS", "VARIANTS", "main", "parser", "train_command"]

#: The models a scenario can train: ``koopbridge train`` flags of each.
VARIANTS: dict[str, list[str]] = {
    "both": ["--model", "koopman", "--normalise"],
    "base": ["--model", "koopman", "--normalise", "--no-ctrl", "--no-cov"],
    "cov": ["--model", "koopman", "--normalise", "--no-ctrl"],
    "ctrl": ["--model", "koopman", "--normalise", "--no-cov"],
    "edmd": ["--model", "edmd"],
    "nndm": ["--model", "nndm"],
}

#: Seed of the references whose closed loops are aggregated in round r: ``AGGREGATION_SEED + r``
#: (the expert data use 42, the held-out references ``go2_track.REFERENCE_SEED``).
AGGREGATION_SEED = 190_042

#: Budgets: CI's smoke run and the paper's (``--full``).
BUDGETS: dict[str, dict[str, Any]] = {
    "smoke": dict(windows=300, train=200, val=50, windows_per_episode=10, block=100, procs=1, iterations=200, n_mult=1,
                  hidden="32,32", validate_every=100, references=4, steps=40, models="both"),
    "full": dict(windows=180_000, train=140_000, val=20_000, windows_per_episode=50, block=2000, procs=2, iterations=20_000, n_mult=16,
                 hidden="256,256,256", validate_every=1000, references=50, steps=300, models="both,base,cov,ctrl,edmd,nndm"),
}


def train_command(variant: str, data: Path, out: Path, b: dict[str, Any], threads: int) -> list[str]:
    """The ``koopbridge train`` command line of ``variant`` on ``data`` with budget ``b``."""
    cmd = [koopbridge_cli(), "train", "--data", str(data), "--out", str(out), *VARIANTS[variant], "--gamma", "0.99",
           "--iterations", str(b["iterations"]), "--n-mult", str(b["n_mult"]), "--hidden", b["hidden"],
           "--validate-every", str(b["validate_every"]), "--threads", str(threads), "--json"]
    if variant == "edmd":
        cmd = [koopbridge_cli(), "train", "--data", str(data), "--out", str(out), *VARIANTS[variant], "--gamma", "0.99", "--json"]
    return cmd


def _run(cmd: list[str], log: Path) -> None:
    print("go2_scenario: $ " + " ".join(cmd), file=sys.stderr, flush=True)
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "wb") as f:
        r = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT)
    if r.returncode != 0:
        tail = log.read_text(errors="replace")[-2000:]
        raise RuntimeError(f"{cmd[0]} {' '.join(cmd[1:3])} failed ({r.returncode}); {log}:\n{tail}")


def _test_pred(model_dir: Path) -> float | None:
    """The model's test L_pred from its ``metrics.json`` (in the model's units: z-scored for a
    model trained with ``--normalise``, raw for EDMD and NNDM), if there."""
    try:
        m = json.loads((model_dir / "metrics.json").read_text())
    except (OSError, ValueError):
        return None
    v = m.get("test_prediction_error")
    return float(v) if isinstance(v, (int, float)) else None


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m koopbridge.experiments.go2_scenario``."""
    p = argparse.ArgumentParser(prog="python -m koopbridge.experiments.go2_scenario", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="Budgets (smoke / --full): " + "; ".join(f"{k}: {BUDGETS['smoke'][k]} / {BUDGETS['full'][k]}" for k in BUDGETS["smoke"]))
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--full", action="store_true", help="the paper's budget (hours) instead of CI's (about a minute)")
    p.add_argument("--data", help="an expert dataset folder to use instead of collecting one (e.g. go2_data's)")
    p.add_argument("--models", help=f"models to train and track, comma separated, from {', '.join(VARIANTS)} (budget's default)")
    p.add_argument("--aggregate", type=int, default=0, help="rounds of on-policy aggregation after the first tracking (default: %(default)s)")
    p.add_argument("--iterations", type=int, help="training iterations (budget's default)")
    p.add_argument("--n-mult", type=int, help="encoder width n_mult (budget's default)")
    p.add_argument("--hidden", help="encoder hidden widths, comma separated (budget's default)")
    p.add_argument("--validate-every", type=int, help="iterations between validations (budget's default)")
    p.add_argument("--references", type=int, help="held-out references (budget's default)")
    p.add_argument("--steps", type=int, help="reference length, steps (budget's default)")
    p.add_argument("--q", default="zscore", help="go2_survival --q (default: %(default)s)")
    p.add_argument("--error-state", action="store_true", help="go2_survival --error-state: also the error-state MPC rows")
    p.add_argument("--threads", type=int, default=2, help="training threads (default: %(default)s)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the scenario; returns the exit code (2: bad arguments, 1: a step failed)."""
    from .go2_survival import SetupError, run
    from .go2_survival import parser as survival_parser
    from .go2_track import make_references
    from .go2_union import union

    a = parser().parse_args(argv)
    b = dict(BUDGETS["full" if a.full else "smoke"])
    for k in ("iterations", "references", "steps", "n_mult", "hidden", "validate_every"):
        if getattr(a, k) is not None:
            b[k] = getattr(a, k)
    models = (a.models or b["models"]).split(",")
    bad = [m for m in models if m not in VARIANTS]
    if bad or a.aggregate < 0 or min(b["iterations"], b["references"], b["steps"], b["n_mult"], b["validate_every"]) < 1:
        print(f"go2_scenario: unknown models {bad} (known: {list(VARIANTS)}) or a count < 1", file=sys.stderr)
        return 2
    out = Path(a.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    summary: dict[str, Any] = dict(budget="full" if a.full else "smoke", settings=b, models=models, rounds=[],
                                   test_pred="the model's test L_pred (gamma 0.99) from its metrics.json, in its own units: "
                                   "z-scored for the Koopman models (--normalise), raw for EDMD and NNDM")
    try:
        data = Path(a.data).resolve() if a.data else out / "data"
        if not a.data:
            _run([sys.executable, "-m", "koopbridge.experiments.go2_data", "--out", str(data), "--windows", str(b["windows"]),
                  "--train", str(b["train"]), "--val", str(b["val"]), "--windows-per-episode", str(b["windows_per_episode"]),
                  "--block", str(b["block"]), "--procs", str(b["procs"])], out / "logs" / "collect.log")
        summary["data"] = str(data)
        summary["collect_s"] = round(time.perf_counter() - t0, 1)
        skipped: list[dict[str, Any]] = []
        refs = make_references(b["references"], b["steps"], skipped=skipped)
        summary["references"] = dict(rollouts=[r.index for r in refs], skipped=skipped)
        for rnd in range(a.aggregate + 1):
            rdir = out / f"round{rnd}"
            t = time.perf_counter()
            dirs = []
            for m in models:
                mdir = rdir / "models" / f"go2-{m}"
                _run(train_command(m, data, mdir, b, a.threads), out / "logs" / f"train-{rnd}-{m}.log")
                dirs.append(mdir)
            train_s = time.perf_counter() - t
            sargs = survival_parser().parse_args(
                [arg for d in dirs for arg in ("--model", str(d))]
                + ["--references", str(b["references"]), "--steps", str(b["steps"]), "--out", str(rdir / "track"), "--q", a.q,
                   "--no-onpolicy"] + (["--error-state"] if a.error_state else []))
            rep = run(sargs, refs)
            entry = dict(round=rnd, data=str(data), train_s=round(train_s, 1),
                         table=[dict(r, test_pred=_test_pred(Path(rep["models"][r["controller"].split(" ")[0]]["dir"])))
                                if not r["controller"].startswith("open-loop") else r for r in rep["table"]],
                         report=str(rdir / "track" / "report.json"))
            summary["rounds"].append(entry)
            if rnd < a.aggregate:
                # The on-policy data come from references of their own (seed AGGREGATION_SEED + round), never
                # from the held-out ones the survival is measured on; each run goes on past the error
                # threshold until the reference ends or the robot falls (recovery data).
                seed = AGGREGATION_SEED + rnd
                aargs = survival_parser().parse_args(
                    ["--model", str(dirs[0]), "--references", str(b["references"]), "--steps", str(b["steps"]), "--seed", str(seed),
                     "--out", str(rdir / "aggregate"), "--q", a.q, "--continue-after-failure", "--no-plot", "--no-mcap"])
                arep = run(aargs)
                first = (arep.get("onpolicy") or {}).get(f"go2-{models[0]}")
                if not first or not first.get("path"):
                    raise RuntimeError(f"round {rnd}: go2-{models[0]} left no on-policy window of {aargs.window_steps} steps to aggregate")
                new = out / f"round{rnd + 1}" / "data"
                u = union(str(data), [first["path"]], str(new))
                entry["aggregated"] = dict(model=f"go2-{models[0]}", reference_seed=seed, windows=first["windows"], union_train=u["train"],
                                           data=str(new), survival_on_them=arep["models"][f"go2-{models[0]}"]["survival"])
                data = new
            write_atomic(str(out / "scenario.json"), lambda f: f.write(json.dumps(summary, indent=2).encode()))  # type: ignore[attr-defined]
    except (SetupError, RuntimeError, FileNotFoundError, ValueError) as e:
        print(f"go2_scenario: {e}", file=sys.stderr)
        return 1
    summary["wall_s"] = round(time.perf_counter() - t0, 1)
    write_atomic(str(out / "scenario.json"), lambda f: f.write(json.dumps(summary, indent=2).encode()))  # type: ignore[attr-defined]
    for e in summary["rounds"]:
        print(json.dumps({"round": e["round"], **{r["controller"]: r.get("mean") for r in e["table"]}}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
