"""The regulariser table on Franka data that cover the figure-8 (issue 26 §4): ``variant`` writes
a variant of ``scenarios/franka-figure8.toml`` for one row (base, +cov, +ctrl, +both, EDMD,
NNDM), one training seed and one MPC weighting (SPEC's Q = I, or the scenario's q̇ weight 0.01),
and ``table`` gathers the runs' SPEC figure-8 errors (``report.json``'s ``figure8``) into a
Markdown table with the mean and spread over seeds.

    python -m koopbridge_experiments.franka_regulariser variant --row both --seed 17382 --q spec --out V.toml
    python -m koopbridge_experiments.franka_regulariser table --runs OUT

``scripts/franka-regulariser-table.sh`` drives both around ``koopbridge run``.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["ROWS", "QS", "main", "parser", "table", "variant"]

#: Row name -> ([train] model kinds, the [train].config entries it adds).
ROWS: dict[str, tuple[str, str]] = {
    "base": ("koopman", "ctrl = false, cov = false"),
    "cov": ("koopman", "ctrl = false, cov = true"),
    "ctrl": ("koopman", "ctrl = true, cov = false"),
    "both": ("koopman", "ctrl = true, cov = true"),
    "edmd": ("edmd", ""),
    "nndm": ("nndm", ""),
}
#: MPC weighting name -> its meaning: ``spec`` drops the scenario's ``q`` (Q = I, SPEC's
#: formulation), ``qd001`` keeps it (q̇ weighted 0.01).
QS = {"spec": "SPEC Q = I", "qd001": "q̇ weight 0.01"}

_TRAIN = re.compile(r"^\[train\]\nconfig = \{ (?P<cfg>[^}]*) \}\n", re.M)
_MPC = re.compile(r"^mpc = \{ horizon = 15, q = \[[^\]]*\] \}\n", re.M)
_AFTER = "figure8_scenario report --u-limit 1.0 --sim arm0 --out {out}"
#: A labelled error-state [[control]] entry of the scenario, with the comment lines right above it.
_ERROR_STATE_ENTRY = re.compile(r'(?:^#[^\n]*\n)*^\[\[control\]\]\nlabel = "error-state[^"]*"\n(?:[^\n\[][^\n]*\n)*\n?', re.M)


_WINDOWS = re.compile(r"^(?P<key>train|val|test)_windows = \d+\n", re.M)


def variant(text: str, row: str, seed: int, q: str, windows: int | None = None, iterations: int | None = None) -> str:
    """The scenario ``text`` (``scenarios/franka-figure8.toml``) for ``row``, training seed
    ``seed`` and weighting ``q``, without the error-state [[control]] entries (not part of the
    table; an NNDM would plan them by random shooting, 0.8 s a step). ``windows`` (training windows; validation and test get a tenth each) and
    ``iterations`` replace the default budget's, when given (``[full]`` is left as it is). Raises
    ``ValueError`` when the file no longer has the expected shape or a budget is not positive."""
    for name, v in (("windows", windows), ("iterations", iterations)):
        if v is not None and v < 1:
            raise ValueError(f"{name} must be a positive count, got {v}")
    if row not in ROWS:
        raise ValueError(f"unknown row {row!r}; valid: {', '.join(ROWS)}")
    if q not in QS:
        raise ValueError(f"unknown weighting {q!r}; valid: {', '.join(QS)}")
    m = _TRAIN.search(text)
    if m is None or len(_MPC.findall(text)) != 1 or text.count(_AFTER) != 1 or not _ERROR_STATE_ENTRY.search(text):
        raise ValueError("the scenario no longer has the [train] config / [control] mpc / error-state [[control]] entries / after-control hook "
                         "lines this variant edits")
    kind, extra = ROWS[row]
    base_cfg = m.group("cfg")
    if iterations is not None:
        base_cfg, n = re.subn(r"iterations = \d+", f"iterations = {iterations}", base_cfg)
        if n != 1:
            raise ValueError("the scenario's [train] config has no iterations entry to replace")
    if kind == "edmd":
        cfg = ""  # EDMD alone refuses the gradient-training settings (least squares, no seed)
    else:
        cfg = ", ".join(p for p in (base_cfg, extra, f"seed = {seed}") if p)
    train = f'[train]\nmodel = ["{kind}"]\nconfig = {{ {cfg} }}\n'
    out = text[: m.start()] + train + text[m.end() :]
    if kind == "edmd":
        # [full].train_config is checked against the kind even without --full; EDMD refuses iterations.
        out = re.sub(r"^train_config = \{[^}]*\}\n", "", out, flags=re.M)
    if windows is not None:
        collect = out.index("[collect]")
        end = out.find("\n[", collect + 1)
        block = out[collect:end]
        sizes = {"train": windows, "val": max(1, windows // 10), "test": max(1, windows // 10)}
        block, n = _WINDOWS.subn(lambda w: f"{w.group('key')}_windows = {sizes[w.group('key')]}\n", block)
        if n != 3:
            raise ValueError("the scenario's [collect] no longer has train/val/test_windows lines")
        out = out[:collect] + block + out[end:]
    if q == "spec":
        out = _MPC.sub("mpc = { horizon = 15 }\n", out)
    out = _ERROR_STATE_ENTRY.sub("", out)
    budget = "" if windows is None and iterations is None else f", budget windows={windows or 'default'} iterations={iterations or 'default'}"
    out = f"# Variant for issue 26 §4: row {row}, seed {seed}, {QS[q]}{budget} (koopbridge_experiments.franka_regulariser).\n" + out
    tomllib.loads(out)  # still a valid TOML file
    return out


def _spread(v: list[float]) -> str:
    if not v:
        return "—"
    if len(v) == 1:
        return f"{v[0]:.3f}"
    return f"{np.mean(v):.3f} ± {np.std(v, ddof=1):.3f} (n={len(v)})"


def table(runs: Path) -> tuple[str, dict[str, Any]]:
    """The Markdown table and the raw errors of the runs ``runs/{row}-s{seed}-{q}/report.json``."""
    errs: dict[str, dict[str, dict[int, float]]] = {r: {q: {} for q in QS} for r in ROWS}
    base_line: dict[str, float] = {}
    pred: dict[str, dict[int, float]] = {r: {} for r in ROWS}
    for rep in sorted(runs.glob("*-s*-*/report.json")):
        m = re.fullmatch(r"(?P<row>[a-z]+)-s(?P<seed>\d+)-(?P<q>[a-z0-9]+)", rep.parent.name)
        if m is None or m["row"] not in ROWS or m["q"] not in QS:
            continue
        report = json.loads(rep.read_text())
        f8 = report.get("figure8")
        if not f8:
            continue
        for entry in report.get("models") or []:
            if entry.get("test_prediction_error") is not None:
                pred[m["row"]][int(m["seed"])] = float(entry["test_prediction_error"])
                break
        errs[m["row"]][m["q"]][int(m["seed"])] = float(f8["errors"]["koopman-mpc"])
        for k in ("zero-input", "joint-follower"):
            base_line.setdefault(k, float(f8["errors"][k]))
    lines = ["| row | test L_pred | SPEC Q = I | q̇ weight 0.01 | vs base (Q = I / q̇ 0.01) | seeds |", "|---|---|---|---|---|---|"]
    for r in ROWS:
        cells, rel = [], []
        for q in QS:
            v = list(errs[r][q].values())
            cells.append(_spread(v))
            b = list(errs["base"][q].values())
            rel.append(f"{100 * (np.mean(v) / np.mean(b) - 1):+.1f} %" if v and b and r != "base" else "—")
        seeds = sorted(set(errs[r]["spec"]) | set(errs[r]["qd001"]))
        lp = list(pred[r].values())
        lines.append(f"| {r} | {np.mean(lp):.3e} | {cells[0]} |" if lp else f"| {r} | — | {cells[0]} |")
        lines[-1] += f" {cells[1]} | {rel[0]} / {rel[1]} | {', '.join(map(str, seeds)) or '—'} |"
    for k, v in base_line.items():
        lines.append(f"| {k} (no model) | | {v:.3f} | {v:.3f} | | |")
    return "\n".join(lines), {"errors": errs, "baselines": base_line, "test_prediction_error": pred}


def parser() -> argparse.ArgumentParser:
    """The command line (subcommands ``variant`` and ``table``)."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.franka_regulariser", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    v = sub.add_parser("variant", help="write a variant of the figure-8 scenario for one row, seed and weighting")
    v.add_argument("--scenario", default="scenarios/franka-figure8.toml", help="the scenario to vary (default: %(default)s)")
    v.add_argument("--row", required=True, choices=list(ROWS), help="the table row: Koopman base/cov/ctrl/both, edmd, nndm")
    v.add_argument("--seed", type=int, default=17382, help="the training seed (default: %(default)s; unused by edmd)")
    v.add_argument("--q", default="spec", choices=list(QS), help="spec: Q = I (SPEC); qd001: the scenario's q (q̇ weight 0.01)")
    v.add_argument("--windows", type=int, help="training windows instead of the scenario's default budget (validation and test: a tenth each)")
    v.add_argument("--iterations", type=int, help="training iterations instead of the scenario's default budget")
    v.add_argument("--out", required=True, help="the variant TOML to write")
    t = sub.add_parser("table", help="gather OUT/{row}-s{seed}-{q}/report.json into a Markdown table")
    t.add_argument("--runs", required=True, help="the driver's output folder")
    t.add_argument("--json", help="also write the raw errors here")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point."""
    a = parser().parse_args(argv)
    try:
        if a.cmd == "variant":
            text = variant(Path(a.scenario).read_text(), a.row, a.seed, a.q, a.windows, a.iterations)
            Path(a.out).parent.mkdir(parents=True, exist_ok=True)
            Path(a.out).write_text(text)
        else:
            md, raw = table(Path(a.runs))
            print(md)
            if a.json:
                Path(a.json).write_text(json.dumps(raw, indent=2))
    except (OSError, ValueError) as e:
        print(f"franka_regulariser: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
