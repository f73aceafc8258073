"""The figure-8 scenario that scores given model folders (the Franka tracking table's runs): no
collection, no training — each model a ``[train] pretrained`` entry and a labelled ``[[control]]``
row naming it, SPEC's MPC with SPEC's observation noise (σ = 0.01 on the end-effector position),
beside zero input and the greedy joint follower; the engine runs every closed loop and the
``figure8_scenario report`` hook scores them (``report.json``'s ``figure8``).

    python -m koopbridge_experiments.figure8_models --model edmd=DIR [--model NAME=DIR ...] --out OUT/figure8.toml [--u-limit 0.3]
    koopbridge run OUT/figure8.toml --out OUT
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

from .dataset_npz import write_atomic
from .figure8_ref import references
from .figure8_scenario import simulator

__all__ = ["BASELINES", "NOISE", "main", "scenario_text"]

#: The rows that need no model, by label.
BASELINES = ("zero-input", "joint-follower")
#: SPEC's observation noise: σ on the end-effector position (states 0–2) the MPC sees.
NOISE = dict(sigma=0.01, states=[0, 1, 2], seed=0)
NAME = re.compile(r"^[a-z0-9_-]+$")


def _toml(v: object) -> str:
    return json.dumps(v, ensure_ascii=False)


def scenario_text(models: Mapping[str, Path], *, u_limit: float = 0.3, steps: int = 3001, horizon: int = 15,
                  q: Sequence[float] | None = None, baselines: bool = True, name: str = "figure8-models") -> str:
    """The scenario (TOML) tracking SPEC's figure-8 of ``steps`` points with each of ``models``
    (row name → model folder; the names ``[a-z0-9_-]``, none a baseline's), the adapter's command
    clip and the MPC's bounds ``±u_limit``, Q = ``q`` (default I), and with ``baselines`` the
    zero-input and joint-follower rows."""
    bad = [n for n in models if not NAME.match(n) or n in BASELINES]
    if bad or not models:
        raise ValueError(f"model row names must match [a-z0-9_-]+ and not be {BASELINES}; got {list(models) or 'none'}")
    if steps < 2 or horizon < 1 or not u_limit > 0:
        raise ValueError(f"steps >= 2, horizon >= 1, u_limit > 0 expected; got {steps}, {horizon}, {u_limit}")
    x0 = [float(v) for v in references(simulator(u_limit=u_limit), 2).x0]
    lim = repr(float(u_limit))
    mpc = dict(horizon=horizon, **({"q": [float(v) for v in q]} if q is not None else {}))
    plan_args = "--plan {out}/figure8-plan.npy --feedforward {out}/figure8-feedforward.npy" if baselines else ""
    pretrained = ", ".join(f"{{ name = {_toml(n)}, path = {_toml(str(Path(p).resolve()))} }}" for n, p in models.items())
    lines = [
        f"name = {_toml(name)}",
        'description = "SPEC\'s figure-8 tracked with models trained elsewhere (koopbridge_experiments.figure8_models)"',
        "[[sims]]", 'id = "arm0"', 'env = "franka-panda"',
        f'command = ["{{python}}", "-m", "koopbridge.adapters.mujoco", "--u-limit", "{lim}"]',
        "[train]", f"pretrained = [{pretrained}]",
        "[[hooks]]", 'phase = "before-control"',
        f'command = "{{python}} -m koopbridge_experiments.figure8_scenario reference --u-limit {lim} --steps {steps} '
        f'--out {{out}}/figure8-reference.npy {plan_args}"',
        "[control_defaults]", 'sim = "arm0"', f"x0 = {_toml(x0)}", f"steps = {steps - 1}",
        'reference_file = "{out}/figure8-reference.npy"',
    ]
    noise = f"{{ sigma = {NOISE['sigma']}, states = {_toml(NOISE['states'])}, seed = {NOISE['seed']} }}"
    for n in models:
        lines += ["[[control]]", f"label = {_toml(n)}", f"model = {_toml(n)}", f"mpc = {_dict(mpc)}", f"observation_noise = {noise}"]
    if baselines:
        lines += ["[[control]]", 'label = "zero-input"', 'controller = "zero-input"',
                  "[[control]]", 'label = "joint-follower"', 'controller = "feedforward"',
                  'reference_file = "{out}/figure8-plan.npy"', 'feedforward_file = "{out}/figure8-feedforward.npy"',
                  "position_loop = { position = [3, 4, 5, 6, 7, 8, 9], velocity = [10, 11, 12, 13, 14, 15, 16], gain = 50.0 }"]
    lines += ["[[hooks]]", 'phase = "after-control"',
              f'command = "{{python}} -m koopbridge_experiments.figure8_scenario report --u-limit {lim} --sim arm0 --out {{out}}"']
    return "\n".join(lines) + "\n"


def _dict(d: Mapping[str, object]) -> str:
    return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in d.items()) + " }"


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m koopbridge_experiments.figure8_models``."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.figure8_models", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", action="append", required=True, metavar="NAME=DIR", help="a row: its name and model folder (repeat)")
    p.add_argument("--out", required=True, help="the scenario file to write")
    p.add_argument("--u-limit", type=float, default=0.3, help="command clip and MPC bounds, rad/s (SPEC: %(default)s)")
    p.add_argument("--steps", type=int, default=3001, help="figure-8 points (SPEC: %(default)s)")
    p.add_argument("--q-weights", help="diagonal of Q, comma separated (default: identity, SPEC)")
    p.add_argument("--no-baselines", action="store_true", help="only the models' rows")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Writes the scenario; returns the exit code (2: bad arguments)."""
    a = parser().parse_args(argv)
    try:
        models = dict(m.split("=", 1) for m in a.model)
        q = [float(v) for v in a.q_weights.split(",")] if a.q_weights else None
        text = scenario_text({k: Path(v) for k, v in models.items()}, u_limit=a.u_limit, steps=a.steps, q=q,
                             baselines=not a.no_baselines)
    except ValueError as e:
        print(f"figure8_models: {e}", file=sys.stderr)
        return 2
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    write_atomic(a.out, lambda f: f.write(text.encode()))  # type: ignore[attr-defined]
    return 0


if __name__ == "__main__":
    sys.exit(main())
