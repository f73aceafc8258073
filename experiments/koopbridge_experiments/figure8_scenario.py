"""The figure-8 steps of ``scenarios/franka-figure8.toml``: ``reference`` writes SPEC's joint
reference (``figure8_ref.references``) as the ``(T, nx)`` ``.npy`` that ``[control]
reference_file`` reads (and, with ``--plan``/``--feedforward``, the plan it defines: the
reference's joint velocities as q̇ and as the feed-forward), ``x0`` prints the start state, and
``report`` (an ``after-control`` hook) scores every closed loop the engine ran on the simulator —
one row per labelled ``[[control]]`` entry: SPEC's MPC, zero input, the greedy joint follower,
the error-state MPC about the plan — with SPEC's error, adds the result to ``report.json`` and
draws ``figure8.png``. No closed loop runs here.

    python -m koopbridge_experiments.figure8_scenario reference --out OUT/figure8-reference.npy [--steps 3001] [--plan OUT/figure8-plan.npy --feedforward OUT/figure8-feedforward.npy]
    python -m koopbridge_experiments.figure8_scenario x0 [--u-limit 1.0]
    python -m koopbridge_experiments.figure8_scenario report --out OUT [--sim arm0] [--u-limit 1.0]

The simulator options (``--state``, ``--u-limit``) must be those of the scenario's adapter: the
references and the start are computed on a ``FrankaSimulator`` built with them.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .dataset_npz import write_atomic
from .figure8_ref import SKIP, Figure8, references, tracking_error
from .run_report import update_report

__all__ = ["SPEC_ROW", "main", "parser", "plan_of", "rows_of", "simulator"]


def simulator(state: str = "ee,q,qd", u_limit: float = 0.3) -> Any:
    """The ``FrankaSimulator`` the scenario's adapter runs (robosuite's Panda, SPEC actuation
    with the command clip ``u_limit``)."""
    from koopbridge.adapters.mujoco.model import PandaOptions
    from koopbridge.adapters.mujoco.sim import FrankaSimulator

    return FrankaSimulator(state=state, options=PandaOptions(u_limit=u_limit))


def write_npy(path: str, a: np.ndarray) -> None:
    """Writes ``a`` as float64 ``.npy`` atomically (the folder is created)."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, lambda f: np.save(f, np.ascontiguousarray(a, dtype="<f8")))  # type: ignore[arg-type]


#: The row name of an unlabelled control entry (SPEC's MPC).
SPEC_ROW = "koopman-mpc"


def rows_of(report: dict[str, Any], sim: str) -> dict[str, dict[str, Any]]:
    """Every closed loop the engine ran on simulator ``sim`` (``report.json``'s ``controls``, else
    its ``control``), by row name: the entry's ``label``, ``koopman-mpc`` without one; raises
    ``KeyError`` naming the simulators there when ``sim`` has none."""
    entries = report.get("controls") or []
    if not entries:
        ctrl = report.get("control")
        entries = ctrl if isinstance(ctrl, list) else [ctrl] if isinstance(ctrl, dict) else []
    rows = {e.get("label") or SPEC_ROW: e for e in entries if e.get("sim") == sim}
    if not rows:
        raise KeyError(f"report.json has no control result for simulator {sim!r} (found {[e.get('sim') for e in entries]})")
    return rows


def plan_of(sim: Any, task: Figure8, u_limit: float) -> tuple[np.ndarray, np.ndarray]:
    """The plan the IK reference defines: the states ``[target, q_ref, q̇]`` with q̇ the joint
    velocities ``(q_ref,k − q_ref,k−1)/dt`` (clipped to ``u_limit``; 0 at k = 0), and those
    velocities as the inputs ``(T − 1, 7)`` (input k drives state k to k + 1)."""
    off = 3 if sim.with_ee else 0
    uff = np.clip(np.diff(task.q, axis=0) / sim.options.dt, -u_limit, u_limit)
    plan = task.x.copy()
    plan[1:, off + 7 : off + 14] = uff
    return plan, uff


def _ee_path(sim: Any, x: np.ndarray) -> np.ndarray:
    """End-effector positions of the states ``x`` by forward kinematics of their q."""
    off = 3 if sim.with_ee else 0
    return np.array([sim.ee_position(xi[off : off + 7]) for xi in x])


def report(out: Path, sim_id: str, state: str, u_limit: float, plot: bool = True) -> dict[str, Any]:
    """Scores every closed loop of simulator ``sim_id`` in ``out/report.json`` (see the module doc)
    with SPEC's error; the deviation figures are SPEC's MPC's (the unlabelled or ``koopman-mpc``
    row, else the first); returns the entry added."""
    rep_path = out / "report.json"
    rows = rows_of(json.loads(rep_path.read_text()), sim_id)
    main_row = SPEC_ROW if SPEC_ROW in rows else next(iter(rows))
    x = np.asarray(rows[main_row]["x"], dtype=float)
    u = np.asarray(rows[main_row]["u"], dtype=float)
    if len(x) <= SKIP + 1:
        raise ValueError(f"the closed loop has {len(x)} states; SPEC's error needs more than {SKIP + 1}")
    sim = simulator(state, u_limit)
    task = references(sim, len(x))
    errors, ee_of = {}, {}
    for name, row in rows.items():
        xr = np.asarray(row["x"], dtype=float)
        ee_of[name] = ee = _ee_path(sim, xr)
        errors[name] = tracking_error(ee, task.targets[: len(xr)])
    dev = np.linalg.norm(ee_of[main_row][:, 1:3] - task.targets[:, 1:3], axis=1)
    entry = dict(
        metric=f"Frobenius norm of the (y, z) end-effector deviation after the first {SKIP} steps (SPEC)",
        steps=len(x) - 1,
        u_limit=u_limit,
        errors=errors,
        rows={name: dict(controller=row.get("controller", "mpc"), error_state=row.get("error_state", False),
                         position_loop=row.get("position_loop"), observation_noise=row.get("observation_noise"))
              for name, row in rows.items()},
        rms_deviation_m=float(np.sqrt(np.mean(dev[SKIP:] ** 2))),
        max_deviation_m=float(dev[SKIP:].max()),
        saturated_fraction=round(float(np.mean(np.abs(u) >= u_limit - 1e-9)), 4),
        max_ref_joint_speed=[round(float(v), 4) for v in np.abs(np.diff(task.q, axis=0)).max(axis=0) / sim.options.dt],
        ik_max_error_m=task.ik_error,
        plot="figure8.png" if plot else None,
    )
    if plot:
        from .figure8_plot import plot as draw

        draw(str(out / "figure8.png"), task, ee_of)
    update_report(rep_path, "figure8", entry)
    return entry


def parser() -> argparse.ArgumentParser:
    """The command line (subcommands ``reference``, ``x0``, ``report``)."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.figure8_scenario", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--state", default="ee,q,qd", help="the adapter's --state (default: %(default)s)")
    common.add_argument("--u-limit", type=float, default=0.3, help="the adapter's --u-limit, rad/s (default: %(default)s)")
    r = sub.add_parser("reference", parents=[common], help="write the (T, nx) joint reference .npy")
    r.add_argument("--out", required=True, help="the .npy to write")
    r.add_argument("--steps", type=int, default=3001, help="points k = 0..steps-1 (SPEC: 3001)")
    r.add_argument("--plan", metavar="NPY",
                   help="also write the plan the reference defines here: its states with q̇ = the reference's joint velocities "
                        "(for [control] reference_file beside feedforward_file; SPEC's reference has q̇ = 0)")
    r.add_argument("--feedforward", metavar="NPY",
                   help="with --plan: the plan's inputs, the reference's joint velocities (T-1, 7) and --horizon zero rows past "
                        "the end, for [control] feedforward_file")
    r.add_argument("--horizon", type=int, default=15, help="zero rows after the feed-forward (the MPC's horizon; default %(default)s)")
    x = sub.add_parser("x0", parents=[common], help="print the start state (JSON) for [control] x0")
    x.add_argument("--steps", type=int, default=2, help=argparse.SUPPRESS)
    rep = sub.add_parser("report", parents=[common], help="score the closed loop of OUT/report.json, draw OUT/figure8.png")
    rep.add_argument("--out", required=True, help="the run's output folder (holds report.json)")
    rep.add_argument("--sim", default="arm0", help="the controlled simulator's id (default: %(default)s)")
    rep.add_argument("--no-plot", action="store_true", help="skip figure8.png")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs a subcommand; returns the exit code (2: bad arguments or input)."""
    a = parser().parse_args(argv)
    if a.cmd == "report":
        try:
            entry = report(Path(a.out), a.sim, a.state, a.u_limit, plot=not a.no_plot)
        except (OSError, KeyError, ValueError) as e:
            print(f"figure8_scenario report: {e}", file=sys.stderr)
            return 2
        print(json.dumps(entry["errors"]))
        return 0
    if a.steps < 2:
        print("figure8_scenario: --steps must be at least 2", file=sys.stderr)
        return 2
    sim = simulator(a.state, a.u_limit)
    task = references(sim, a.steps)
    if a.cmd == "x0":
        print(json.dumps([round(float(v), 12) for v in task.x0]))
        return 0
    if (a.plan is None) != (a.feedforward is None):
        print("figure8_scenario reference: --plan and --feedforward go together", file=sys.stderr)
        return 2
    write_npy(a.out, task.x)
    if a.plan:
        plan, uff = plan_of(sim, task, a.u_limit)
        write_npy(a.plan, plan)
        # Past the plan's end the MPC's window sees zero velocity (the arm brought to rest).
        write_npy(a.feedforward, np.concatenate([uff, np.zeros((max(a.horizon, 0), uff.shape[1]))]))
    print(f"figure8 reference: {task.x.shape} to {a.out} (IK error <= {task.ik_error:.2e} m)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
