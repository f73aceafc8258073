"""A legged robot's survival scenario end to end, robot-agnostic (issues 25 §3 and 30): collect
expert data (the robot's ``*_data``) → train (``koopbridge train --normalise --gamma 0.99``; EDMD
and NNDM on raw units) → track held-out references through the bridge (``legged_survival``) →
report, with optional rounds of on-policy aggregation. The robot is a ``ScenarioRobot`` of
``SCENARIOS``; ``go2_scenario`` and ``g1_scenario`` are the command lines (their docstrings say
what is written where).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .dataset_npz import write_atomic
from .figure8 import koopbridge_cli
from .legged_survival import G1, GO2, LeggedRobot

__all__ = ["AGGREGATION_SEED", "BUDGETS", "G1_SCENARIO", "GO2_SCENARIO", "SCENARIOS", "VARIANTS", "ScenarioRobot", "main", "parser",
           "train_command"]


def _no_args(p: argparse.ArgumentParser) -> None:
    return None


def _none(a: argparse.Namespace) -> list[str]:
    return []


def _g1_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--held", choices=("servo", "locked"), default="locked", help="the G1's 6 non-input joints locked rigid (the 23-DoF "
                   "G1) or held by their servos, for the data and the tracking (default: %(default)s)")
    p.add_argument("--expert", choices=("fastsac", "ppo"), default="fastsac", help="the walking policy (default: %(default)s)")


def _g1_flags(a: argparse.Namespace) -> list[str]:
    return ["--held", a.held, "--expert", a.expert]


@dataclass(frozen=True)
class ScenarioRobot:
    """A robot's scenario: its survival task (``robot``), its dataset command line's module
    (``data``), its own options (``add_args``) and the flags they give to both the data and the
    survival command lines (``flags``), and the smoke budget's changes (``smoke``)."""

    robot: LeggedRobot
    data: str
    add_args: Callable[[argparse.ArgumentParser], None] = _no_args
    flags: Callable[[argparse.Namespace], list[str]] = _none
    smoke: tuple[tuple[str, Any], ...] = ()

    @property
    def prog(self) -> str:
        """The command line's module name (``{robot}_scenario``)."""
        return f"{self.robot.name}_scenario"


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


def _run(cmd: list[str], log: Path, prog: str = "go2_scenario") -> None:
    print(f"{prog}: $ " + " ".join(cmd), file=sys.stderr, flush=True)
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


def budgets(sr: ScenarioRobot) -> dict[str, dict[str, Any]]:
    """The robot's budgets: ``BUDGETS`` with its smoke changes and its reference length at ``full``."""
    return dict(smoke={**BUDGETS["smoke"], **dict(sr.smoke)}, full={**BUDGETS["full"], "steps": sr.robot.steps})


def parser(sr: ScenarioRobot, description: str) -> argparse.ArgumentParser:
    """The command line of ``python -m koopbridge.experiments.{sr.prog}``."""
    bs = budgets(sr)
    p = argparse.ArgumentParser(prog=f"python -m koopbridge.experiments.{sr.prog}", description=description,
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="Budgets (smoke / --full): " + "; ".join(f"{k}: {bs['smoke'][k]} / {bs['full'][k]}" for k in bs["smoke"]))
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--full", action="store_true", help="the paper's budget (hours) instead of CI's (about a minute)")
    p.add_argument("--data", help=f"an expert dataset folder to use instead of collecting one (e.g. {sr.data}'s)")
    p.add_argument("--models", help=f"models to train and track, comma separated, from {', '.join(VARIANTS)} (budget's default)")
    p.add_argument("--aggregate", type=int, default=0, help="rounds of on-policy aggregation after the first tracking (default: %(default)s)")
    p.add_argument("--iterations", type=int, help="training iterations (budget's default)")
    p.add_argument("--n-mult", type=int, help="encoder width n_mult (budget's default)")
    p.add_argument("--hidden", help="encoder hidden widths, comma separated (budget's default)")
    p.add_argument("--validate-every", type=int, help="iterations between validations (budget's default)")
    p.add_argument("--references", type=int, help="held-out references (budget's default)")
    p.add_argument("--steps", type=int, help="reference length, steps (budget's default)")
    p.add_argument("--q", default="zscore", help=f"{sr.robot.prog} --q (default: %(default)s)")
    p.add_argument("--error-state", action="store_true", help=f"{sr.robot.prog} --error-state: also the recommended controller's rows "
                   "(error-state MPC, Q on the joints, R = I)")
    p.add_argument("--noise", type=float, default=0.0, help=f"{sr.data} --noise: sigma (rad) on the expert's targets while collecting "
                   "(default: %(default)s, the paper's expert data; the scenario files use 0.2, docs/decisions/0017)")
    p.add_argument("--threads", type=int, default=2, help="training threads (default: %(default)s)")
    sr.add_args(p)
    return p


def main(sr: ScenarioRobot, argv: Sequence[str] | None = None, description: str = "") -> int:
    """Runs robot ``sr``'s scenario; returns the exit code (2: bad arguments, 1: a step failed)."""
    from .go2_union import union
    from .legged_survival import SetupError, references, run
    from .legged_survival import parser as legged_parser

    robot, prog = sr.robot, sr.prog
    a = parser(sr, description).parse_args(argv)
    flags = sr.flags(a)

    def survival_args(args: list[str]) -> argparse.Namespace:
        return legged_parser(robot, "").parse_args(args + flags)

    b = dict(budgets(sr)["full" if a.full else "smoke"])
    for k in ("iterations", "references", "steps", "n_mult", "hidden", "validate_every"):
        if getattr(a, k) is not None:
            b[k] = getattr(a, k)
    models = (a.models or b["models"]).split(",")
    bad = [m for m in models if m not in VARIANTS]
    if bad or a.aggregate < 0 or min(b["iterations"], b["references"], b["steps"], b["n_mult"], b["validate_every"]) < 1:
        print(f"{prog}: unknown models {bad} (known: {list(VARIANTS)}) or a count < 1", file=sys.stderr)
        return 2
    if not (math.isfinite(a.noise) and a.noise >= 0):
        print(f"{prog}: --noise must be a finite number >= 0, got {a.noise}", file=sys.stderr)
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
            _run([sys.executable, "-m", f"koopbridge.experiments.{sr.data}", "--out", str(data), "--windows", str(b["windows"]),
                  "--train", str(b["train"]), "--val", str(b["val"]), "--windows-per-episode", str(b["windows_per_episode"]),
                  "--block", str(b["block"]), "--procs", str(b["procs"]), "--noise", str(a.noise), *flags], out / "logs" / "collect.log", prog)
        summary["data"] = str(data)
        summary["collect_s"] = round(time.perf_counter() - t0, 1)
        skipped: list[dict[str, Any]] = []
        refs = references(robot, b["references"], b["steps"], a=a, skipped=skipped)
        summary["references"] = dict(rollouts=[r.index for r in refs], skipped=skipped)
        for rnd in range(a.aggregate + 1):
            rdir = out / f"round{rnd}"
            t = time.perf_counter()
            dirs = []
            for m in models:
                mdir = rdir / "models" / f"{robot.name}-{m}"
                _run(train_command(m, data, mdir, b, a.threads), out / "logs" / f"train-{rnd}-{m}.log", prog)
                dirs.append(mdir)
            train_s = time.perf_counter() - t
            sargs = survival_args(
                [arg for d in dirs for arg in ("--model", str(d))]
                + ["--references", str(b["references"]), "--steps", str(b["steps"]), "--out", str(rdir / "track"), "--q", a.q,
                   "--no-onpolicy"] + (["--error-state"] if a.error_state else []))
            rep = run(robot, sargs, refs)
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
                aargs = survival_args(
                    ["--model", str(dirs[0]), "--references", str(b["references"]), "--steps", str(b["steps"]), "--seed", str(seed),
                     "--out", str(rdir / "aggregate"), "--q", a.q, "--continue-after-failure", "--no-plot", "--no-mcap"])
                arep = run(robot, aargs)
                first = (arep.get("onpolicy") or {}).get(f"{robot.name}-{models[0]}")
                if not first or not first.get("path"):
                    raise RuntimeError(f"round {rnd}: {robot.name}-{models[0]} left no on-policy window of {aargs.window_steps} steps to aggregate")
                new = out / f"round{rnd + 1}" / "data"
                u = union(str(data), [first["path"]], str(new))
                entry["aggregated"] = dict(model=f"{robot.name}-{models[0]}", reference_seed=seed, windows=first["windows"], union_train=u["train"],
                                           data=str(new), survival_on_them=arep["models"][f"{robot.name}-{models[0]}"]["survival"])
                data = new
            write_atomic(str(out / "scenario.json"), lambda f: f.write(json.dumps(summary, indent=2).encode()))  # type: ignore[attr-defined]
    except (SetupError, RuntimeError, FileNotFoundError, ValueError) as e:
        print(f"{prog}: {e}", file=sys.stderr)
        return 1
    summary["wall_s"] = round(time.perf_counter() - t0, 1)
    write_atomic(str(out / "scenario.json"), lambda f: f.write(json.dumps(summary, indent=2).encode()))  # type: ignore[attr-defined]
    for e in summary["rounds"]:
        print(json.dumps({"round": e["round"], **{r["controller"]: r.get("mean") for r in e["table"]}}))
    return 0



#: The Go2's scenario (issue 25).
GO2_SCENARIO = ScenarioRobot(robot=GO2, data="go2_data")
#: The G1's scenario (issue 30): the 23-DoF G1 (``--held locked``) by default; its smoke budget
#: walks 40 steps of 4 references as the Go2's does.
G1_SCENARIO = ScenarioRobot(robot=G1, data="g1_data", add_args=_g1_args, flags=_g1_flags)
#: The scenarios by robot name.
SCENARIOS: dict[str, ScenarioRobot] = {s.robot.name: s for s in (GO2_SCENARIO, G1_SCENARIO)}
