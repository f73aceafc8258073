"""The paper's two Franka tables (issue 10) in one resumable command: SPEC's dataset, the
prediction table (EDMD, NNDM, Koopman base / +ctrl / +cov / +both at n_mult 16 and m = 140k) with
the +both m-sweep and α_m, and the figure-8 tracking table (every model's MPC in one ``koopbridge
run`` per column of a ``figure8_models`` scenario: the MuJoCo adapter in lockstep, the MPC service
deciding every step, SPEC's observation noise, zero input and the greedy joint follower beside),
written as ``tables.md`` and ``tables.json`` beside the paper's figures.

    python -m koopbridge_experiments.franka_tables --out results/franka-tables [--iterations 60000]

Every stage skips what is already there and the trainings resume from their checkpoints, so an
interrupted run (a closed session, a reboot) continues where it stopped when run again. At SPEC's
budget this is hours on 2 cores: nine neural trainings of 60,000 iterations at N = 289, and the
NNDM's random-shooting MPC (1000 rollouts of 15 steps per control step) for 3,000 steps.

Besides SPEC's formulation (Q = I on the 17-D state, whose q̇ reference is 0, clip ±0.3 rad/s)
the tracking table has a column per variant: the clip at ±1.0 rad/s (``--also-u-limits``; SPEC's
path asks up to 0.9 rad/s of joint 4, so the joint follower and the NNDM's sampled inputs saturate at
±0.3), and Q with weight 0.01 on q̇ (``--velocity-weight``): with Q = I the q̇ = 0 reference
weighs like an input penalty of 1 against position moves of 0.02·u per step, and every model's
MPC lags the path.
``--dry-run`` prints the stages and what each would run.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from koopbridge.cli_path import koopbridge_cli

from .dataset_npz import write_atomic

__all__ = ["PAPER", "main", "parser", "stages", "tables"]

#: The paper's figures (Tables "baseline_pred" and "baseline_control", α_m of the Franka).
PAPER = dict(
    prediction={"edmd": 0.441, "nndm": 0.268, "koopman-base": 0.122, "koopman-both": 0.121},
    tracking={"edmd": 0.442, "nndm": 0.514, "koopman-base": 0.437, "koopman-both": 0.256},
    gain_over_base={"koopman-cov": 0.062, "koopman-ctrl": 0.143, "koopman-both": 0.251},
    alpha_m=0.49,
)
#: Regulariser settings of the sweep and the model names they give in the tables.
VARIANTS = {"none": "koopman-base", "ctrl": "koopman-ctrl", "cov": "koopman-cov", "both": "koopman-both"}
SEED, N_MULT = 17382, 16


class Stage:
    """One step of the pipeline: done when every path of ``outputs`` exists (never, for an empty
    list: a cheap stage that always runs), ``cmd`` runs it after ``prepare`` (if any) wrote what
    it reads."""

    def __init__(self, name: str, outputs: list[Path], cmd: list[str], prepare: Callable[[], None] | None = None):
        self.name, self.outputs, self.cmd, self.prepare = name, outputs, cmd, prepare

    @property
    def done(self) -> bool:
        """Whether every output is there."""
        return bool(self.outputs) and all(p.exists() for p in self.outputs)


def _sweep_name(data: Path, m: int, reg: str, iterations: int | None) -> str:
    # The sweep's run names: `{data}-m{m}-n{n_mult}-s{seed}-{regularisers}` (+ `-i{it}` off SPEC).
    suffix = f"-i{iterations}" if iterations and iterations != 60_000 else ""
    return f"{data.name}-m{m}-n{N_MULT}-s{SEED}-{reg}{suffix}"


def stages(a: argparse.Namespace) -> list[Stage]:
    """The pipeline for the arguments ``a``, in order."""
    out, data = Path(a.out), Path(a.data)
    kb, py = koopbridge_cli(), sys.executable
    it = ["--iterations", str(a.iterations)] if a.iterations != 60_000 else []
    sweep = out / "sweep"
    common = [kb, "sweep", "--data", str(data), "--n-mult", str(N_MULT), "--seeds", str(SEED), "--out", str(sweep),
              "--local-trainers", str(a.trainers), "--train-threads", str(a.threads), *it]
    ms = [m for m in a.samples if m != a.table_samples] or [a.table_samples]
    run = lambda m, reg: sweep / "runs" / _sweep_name(data, m, reg, a.iterations) / "metrics.json"  # noqa: E731
    s = [
        Stage("data: SPEC's Franka dataset (MuJoCo collect, U(±0.12), seed 42)", [data / f"{k}.npz" for k in ("train", "val", "test")],
              [py, "-m", "koopbridge_experiments.franka_data", "--windows", str(a.windows), "--out", str(data),
               "--procs", str(a.trainers)]),
        Stage(f"prediction: Koopman base/+ctrl/+cov/+both at m = {a.table_samples}", [run(a.table_samples, reg) for reg in VARIANTS],
              [*common, "--samples", str(a.table_samples), "--regularisers", ",".join(VARIANTS)]),
        Stage("prediction: EDMD (polynomial)", [out / "models" / "edmd" / "metrics.json"],
              [kb, "train", "--model", "edmd", "--data", str(data), "--out", str(out / "models" / "edmd")]),
        Stage("prediction: NNDM (restarts from scratch if interrupted)", [out / "models" / "nndm" / "metrics.json"],
              [kb, "train", "--model", "nndm", "--data", str(data), "--out", str(out / "models" / "nndm"),
               "--threads", str(a.trainers * a.threads), *it]),
    ]
    for label, folder, extra in _columns(a):
        s.append(Stage(f"tracking: figure-8 with every model, {label} (koopbridge run, no collection)",
                       [folder / "figure8.png"], [kb, "run", str(folder / "figure8.toml"), "--out", str(folder)],
                       prepare=lambda folder=folder, extra=extra: _write_scenario(a, folder, extra)))
    # The m-sweep last: both tables are complete before its four extra trainings start.
    s += [Stage("prediction: the +both m-sweep", [run(m, "both") for m in ms],
                [*common, "--samples", ",".join(map(str, ms)), "--regularisers", "both"]),
          Stage("prediction: α_m of +both (refitted every time)", [],
                [kb, "scaling", str(sweep / "runs"), "--out", str(out / "scaling")])]
    return s


def _columns(a: argparse.Namespace) -> list[tuple[str, Path, dict[str, Any]]]:
    """The tracking table's columns, SPEC's first: (label, run folder, ``figure8_models``
    settings)."""
    out = Path(a.out)
    cols = [(f"clip ±{a.u_limit:g} rad/s", out / "figure8", dict(u_limit=a.u_limit))]
    cols += [(f"clip ±{lim:g} rad/s", out / f"figure8-clip{lim:g}", dict(u_limit=lim)) for lim in a.also_u_limits]
    if a.velocity_weight is not None:
        q = [1.0] * 10 + [a.velocity_weight] * 7
        cols.append((f"q̇ weight {a.velocity_weight:g}", out / f"figure8-qd{a.velocity_weight:g}", dict(u_limit=a.u_limit, q=q)))
    return cols


def _write_scenario(a: argparse.Namespace, folder: Path, settings: dict[str, Any]) -> None:
    """Writes ``folder/figure8.toml``: the figure-8 with every row's model (``figure8_models``)."""
    from .figure8_models import scenario_text

    folder.mkdir(parents=True, exist_ok=True)
    text = scenario_text(_tracked(a), steps=a.steps, name="franka-tables-" + re.sub(r"[^a-z0-9_-]", "-", folder.name), **settings)
    write_atomic(str(folder / "figure8.toml"), lambda f: f.write(text.encode()))  # type: ignore[attr-defined]


def _tracked(a: argparse.Namespace) -> dict[str, Path]:
    """The model folder of each row of the tables."""
    out, data = Path(a.out), Path(a.data)
    rows = {"edmd": out / "models" / "edmd", "nndm": out / "models" / "nndm"}
    for reg, name in VARIANTS.items():
        rows[name] = out / "sweep" / "runs" / _sweep_name(data, a.table_samples, reg, a.iterations)
    return rows


def _read(path: Path) -> dict[str, Any] | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def tables(a: argparse.Namespace) -> dict[str, Any]:
    """Both tables from what the stages wrote (missing entries are ``None``)."""
    out = Path(a.out)
    extra = _columns(a)[1:]
    rows: dict[str, Any] = {}
    spec = _figure8(out / "figure8")
    also = {label: _figure8(folder) for label, folder, _ in extra}  # each column's report read once
    for name, model in _tracked(a).items():
        metrics = _read(model / "metrics.json") or {}
        rows[name] = dict(prediction=metrics.get("test_prediction_error"), tracking=spec["errors"].get(name),
                          solve_median_us=spec["solve_median_us"].get(name), model=str(model),
                          tracking_also={label: run["errors"].get(name) for label, run in also.items()})
    base = rows["koopman-base"]["tracking"]
    for name in VARIANTS.values():
        t = rows[name]["tracking"]
        rows[name]["gain_over_base"] = (base - t) / base if base and t is not None else None
    baselines = _baselines(spec)
    baselines_also = {label: _baselines(run) for label, run in also.items()}
    scaling = _read(out / "scaling" / "scaling.json")
    return dict(rows=rows, baselines=baselines, baselines_also=baselines_also, scaling=scaling, paper=PAPER,
                settings=dict(iterations=a.iterations, table_samples=a.table_samples, samples=a.samples, u_limit=a.u_limit,
                              also_u_limits=a.also_u_limits, velocity_weight=a.velocity_weight, steps=a.steps, data=str(a.data)))


def _figure8(folder: Path) -> dict[str, dict[str, Any]]:
    """The figure-8 run in ``folder``: SPEC's error of every row (``report.json``'s ``figure8``)
    and the MPC rows' median solve times (µs); empty where it has not run."""
    report = _read(folder / "report.json") or {}
    solve = {c.get("label"): c.get("solve_median_us") for c in report.get("controls", []) if c.get("controller") == "mpc"}
    return dict(errors=(report.get("figure8") or {}).get("errors", {}), solve_median_us=solve)


def _baselines(run: dict[str, dict[str, Any]]) -> dict[str, float]:
    """The baselines' tracking errors (the rows that need no model) of a figure-8 run."""
    from .figure8_models import BASELINES

    return {k: v for k, v in run["errors"].items() if k in BASELINES}


def _alpha_m_fit(scaling: dict[str, Any] | None) -> dict[str, Any]:
    """The fit of the +both curve of ``koopbridge scaling``'s ``scaling.json`` (empty if none)."""
    for c in (scaling or {}).get("curves", []):
        if "both" in c.get("label", "") and c.get("fit"):
            return dict(c["fit"])
    return {}


def _markdown(t: dict[str, Any]) -> str:
    f = lambda v, d=4: "—" if v is None else (f"{v:.{d}g}" if isinstance(v, float) else str(v))  # noqa: E731
    p = t["paper"]
    lines = [f"Franka tables (issue 10): {t['settings']['iterations']} iterations, m = {t['settings']['table_samples']}, n_mult 16, "
             f"figure-8 clip ±{t['settings']['u_limit']} rad/s, {t['settings']['steps']} points", "",
             "| model | test L_pred | paper | figure-8 error | paper | gain over base | paper gain | solve median µs |"
             + "".join(f" error, {label} |" for label in t["baselines_also"]),
             "|---|---|---|---|---|---|---|---|" + "---|" * len(t["baselines_also"])]
    pct = lambda v: "—" if v is None else f"{100 * v:.1f} %"  # noqa: E731
    for name, r in t["rows"].items():
        lines.append(f"| {name} | {f(r['prediction'])} | {f(p['prediction'].get(name))} | {f(r['tracking'])} | "
                     f"{f(p['tracking'].get(name))} | {pct(r.get('gain_over_base'))} | {pct(p['gain_over_base'].get(name))} | "
                     f"{f(r['solve_median_us'])} |" + "".join(f" {f(v)} |" for v in r["tracking_also"].values()))
    for k, v in t["baselines"].items():
        lines.append(f"| baseline: {k} | | | {f(v)} | | | | |" + "".join(f" {f(b.get(k))} |" for b in t["baselines_also"].values()))
    fit = _alpha_m_fit(t["scaling"])
    lines += ["", f"α_m of +both: {f(fit.get('alpha'))} (paper {p['alpha_m']}), A {f(fit.get('a'))}, C {f(fit.get('c'))}, "
              f"R² {f(fit.get('r2'))}, {fit.get('points', 0)} points (scaling/scaling.png)"]
    return "\n".join(lines) + "\n"


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m koopbridge_experiments.franka_tables``."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.franka_tables", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 2)[2])
    p.add_argument("--out", required=True, help="the tables' folder (sweep/, models/, figure8/, tables.md, tables.json)")
    p.add_argument("--data", help="SPEC's Franka dataset folder, collected there if missing (default: OUT/data)")
    p.add_argument("--windows", type=int, default=180_000, help="dataset windows, 140k/20k/20k (default: %(default)s)")
    p.add_argument("--iterations", type=int, default=60_000, help="training iterations of every neural model (SPEC: %(default)s)")
    p.add_argument("--table-samples", type=int, default=140_000, help="training windows m of the tables' models (SPEC: %(default)s)")
    p.add_argument("--samples", type=lambda s: [int(v) for v in s.split(",")], default=[1000, 4000, 16000, 64000, 140000],
                   help="the +both m-sweep (default: 1000,4000,16000,64000,140000)")
    p.add_argument("--trainers", type=int, default=2, help="trainer processes of the sweeps, collecting processes (default: %(default)s)")
    p.add_argument("--threads", type=int, default=1, help="threads per trainer (default: %(default)s)")
    p.add_argument("--u-limit", type=float, default=0.3, help="figure-8 command clip, rad/s (SPEC: %(default)s; "
                   "scenarios/franka-figure8.toml uses 1.0, why: its header)")
    p.add_argument("--also-u-limits", type=lambda s: [float(v) for v in s.split(",") if v], default=[1.0],
                   help="run the figure-8 at these command clips too, rad/s, a table column each (default: 1.0, where "
                   "SPEC's path is within reach; '' for none)")
    p.add_argument("--velocity-weight", type=lambda s: float(s) if s else None, default=0.01,
                   help="a figure-8 column with this weight on q̇ in Q (1 elsewhere; SPEC's clip) (default: %(default)s; '' for none)")
    p.add_argument("--steps", type=int, default=3001, help="figure-8 points (SPEC: %(default)s)")
    p.add_argument("--dry-run", action="store_true", help="print the stages and their commands, run nothing")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the missing stages, then writes the tables; returns the exit code."""
    a = parser().parse_args(argv)
    a.data = a.data or str(Path(a.out) / "data")
    out = Path(a.out)
    todo = stages(a)
    for i, st in enumerate(todo, 1):
        state = "done" if st.done else "to run"
        print(f"[{i}/{len(todo)}] {st.name}: {state}", flush=True)
        if a.dry_run:
            print("    " + " ".join(st.cmd), flush=True)
            continue
        if st.done:
            continue
        t = time.monotonic()
        if st.prepare:
            st.prepare()
        r = subprocess.run(st.cmd)
        if r.returncode != 0:
            print(f"franka_tables: stage '{st.name}' failed (exit {r.returncode}); rerun to resume", file=sys.stderr)
            return 1
        print(f"    done in {time.monotonic() - t:.0f} s", flush=True)
    if a.dry_run:
        return 0
    t = tables(a)
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(str(out / "tables.json"), lambda f: f.write(json.dumps(t, indent=2).encode()))  # type: ignore[attr-defined]
    md = _markdown(t)
    write_atomic(str(out / "tables.md"), lambda f: f.write(md.encode()))  # type: ignore[attr-defined]
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
