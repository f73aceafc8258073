"""The figure-8 steps of ``scenarios/franka-figure8.toml``: ``reference`` writes SPEC's joint
reference (``figure8_ref.references``) as the ``(T, nx)`` ``.npy`` that ``[control]
reference_file`` reads, ``x0`` prints the start state, and ``report`` (an ``after-control``
hook) scores the orchestrator's closed loop with SPEC's error against zero input, the greedy
joint follower and the error-state Koopman MPC about the reference's plan (its joint velocities
as feed-forward; the run's model, in-process) on the same simulator, adds the result to
``report.json`` and draws ``figure8.png``.

    python -m koopbridge_experiments.figure8_scenario reference --out OUT/figure8-reference.npy [--steps 3001] [--feedforward OUT/figure8-feedforward.npy]
    python -m koopbridge_experiments.figure8_scenario x0 [--u-limit 1.0]
    python -m koopbridge_experiments.figure8_scenario report --out OUT [--sim arm0] [--u-limit 1.0]

The simulator options (``--state``, ``--u-limit``) must be those of the scenario's adapter: the
references, the start and the baselines are computed on a ``FrankaSimulator`` built with them.
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
from .figure8_ref import SKIP, Figure8, joint_p_command, references, tracking_error
from .run_report import update_report

__all__ = ["closed_loop_of", "main", "parser", "plan_of", "simulator"]


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


def closed_loop_of(report: dict[str, Any], sim: str) -> dict[str, Any]:
    """The orchestrator's control result of simulator ``sim`` in ``report.json`` (``control``
    may be one result or a list of them); raises ``KeyError`` naming what is there."""
    ctrl = report.get("control")
    entries = ctrl if isinstance(ctrl, list) else [ctrl] if isinstance(ctrl, dict) else []
    for e in entries:
        if e.get("sim") == sim:
            return e
    raise KeyError(f"report.json has no control result for simulator {sim!r} (found {[e.get('sim') for e in entries]})")


def _baseline(sim: Any, task: Figure8, kind: str, u_limit: float) -> np.ndarray:
    """States of zero input or the greedy joint follower (gain 1/dt) over the task, in-process."""
    x = sim.reset(x0=task.x0)
    xs = [x]
    off = 3 if sim.with_ee else 0
    for k in range(len(task.x) - 1):
        u = np.zeros(7) if kind == "zero" else joint_p_command(x[off : off + 7], task.q[k + 1], 1.0 / sim.options.dt, u_limit)
        x = sim.step(u)
        xs.append(x)
    return np.array(xs)


def plan_of(sim: Any, task: Figure8, u_limit: float) -> tuple[np.ndarray, np.ndarray]:
    """The plan the IK reference defines: the states ``[target, q_ref, q̇]`` with q̇ the joint
    velocities ``(q_ref,k − q_ref,k−1)/dt`` (clipped to ``u_limit``; 0 at k = 0), and those
    velocities as the inputs ``(T − 1, 7)`` (input k drives state k to k + 1)."""
    off = 3 if sim.with_ee else 0
    uff = np.clip(np.diff(task.q, axis=0) / sim.options.dt, -u_limit, u_limit)
    plan = task.x.copy()
    plan[1:, off + 7 : off + 14] = uff
    return plan, uff


def _error_state(sim: Any, task: Figure8, model: str, u_limit: float, horizon: int = 15, position_gain: float = 0.0) -> np.ndarray:
    """States of the error-state Koopman MPC (``koopbridge.Mpc``, SPEC's Q = I, R = 0) about
    the reference's plan (``plan_of``: its joint velocities as feed-forward); in-process. With a
    ``position_gain`` (1/s) the plan is first corrected by a position loop: its velocities (the
    inputs and the planned state's q̇ alike) minus gain · (q − q_ref)."""
    from koopbridge import Mpc

    from .plan_loop import corrected_plan

    off = 3 if sim.with_ee else 0
    plan, uff = plan_of(sim, task, u_limit)
    uff_h = np.concatenate([uff, np.zeros((horizon, 7))])
    mpc = Mpc(model, horizon=horizon, u_min=[-u_limit] * 7, u_max=[u_limit] * 7)
    x = sim.reset(x0=task.x0)
    xs = [x]
    for k in range(len(task.x) - 1):
        r, ff = corrected_plan(x, plan[k], uff_h[k : k + horizon], slice(off, off + 7), slice(off + 7, off + 14), position_gain, u_limit)
        x = sim.step(np.asarray(mpc.solve(x, r, feedforward=ff)["u"])[0])
        xs.append(x)
    return np.array(xs)


def _ee_path(sim: Any, x: np.ndarray) -> np.ndarray:
    """End-effector positions of the states ``x`` by forward kinematics of their q."""
    off = 3 if sim.with_ee else 0
    return np.array([sim.ee_position(xi[off : off + 7]) for xi in x])


def report(out: Path, sim_id: str, state: str, u_limit: float, plot: bool = True, error_state: bool = True) -> dict[str, Any]:
    """Scores the closed loop in ``out/report.json`` (see the module doc); returns the entry added.
    ``error_state``: also run the error-state MPC about the reference's plan with the run's model."""
    from .figure8 import Run

    rep_path = out / "report.json"
    ctrl = closed_loop_of(json.loads(rep_path.read_text()), sim_id)
    x = np.asarray(ctrl["x"], dtype=float)
    u = np.asarray(ctrl["u"], dtype=float)
    if len(x) <= SKIP + 1:
        raise ValueError(f"the closed loop has {len(x)} states; SPEC's error needs more than {SKIP + 1}")
    sim = simulator(state, u_limit)
    task = references(sim, len(x))
    runs = [Run("koopman-mpc", np.c_[_ee_path(sim, x), x] if not sim.with_ee else x, u, [], [], 0.0, {})]
    errors = {"koopman-mpc": tracking_error(_ee_path(sim, x), task.targets)}
    for kind, name in (("zero", "zero-input"), ("p", "joint-follower")):
        xb = _baseline(sim, task, kind, u_limit)
        ee = _ee_path(sim, xb)
        errors[name] = tracking_error(ee, task.targets)
        runs.append(Run(name, np.c_[ee, xb] if not sim.with_ee else xb, np.zeros((len(xb) - 1, 7)), [], [], 0.0, {}))
    if error_state and ctrl.get("model"):
        # Not SPEC's formulation (q̇_ref = 0): the deviation from the plan the reference defines,
        # as it is and corrected by a position loop (gain 30/s).
        for name, gain in (("error-state-mpc", 0.0), ("error-state-mpc+position-loop", 30.0)):
            xe = _error_state(sim, task, str(out / "models" / ctrl["model"]), u_limit, position_gain=gain)
            ee = _ee_path(sim, xe)
            errors[name] = tracking_error(ee, task.targets)
            runs.append(Run(name, np.c_[ee, xe] if not sim.with_ee else xe, np.zeros((len(xe) - 1, 7)), [], [], 0.0, {}))
    dev = np.linalg.norm(_ee_path(sim, x)[:, 1:3] - task.targets[:, 1:3], axis=1)
    entry = dict(
        metric=f"Frobenius norm of the (y, z) end-effector deviation after the first {SKIP} steps (SPEC)",
        steps=len(x) - 1,
        u_limit=u_limit,
        errors=errors,
        rms_deviation_m=float(np.sqrt(np.mean(dev[SKIP:] ** 2))),
        max_deviation_m=float(dev[SKIP:].max()),
        saturated_fraction=round(float(np.mean(np.abs(u) >= u_limit - 1e-9)), 4),
        max_ref_joint_speed=[round(float(v), 4) for v in np.abs(np.diff(task.q, axis=0)).max(axis=0) / sim.options.dt],
        ik_max_error_m=task.ik_error,
        baselines="zero input and the greedy joint follower u = clip((q_ref,k+1 - q_k)/dt, ±u_limit), in-process on the same simulator"
        + ("; error-state-mpc: the run's model, Q = I, feed-forward = the reference's joint velocities, in-process; "
           "+position-loop: that plan's velocities minus 30/s · (q − q_ref)" if "error-state-mpc" in errors else ""),
        plot="figure8.png" if plot else None,
    )
    if plot:
        from .figure8_plot import plot as draw

        draw(str(out / "figure8.png"), task, runs)
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
    r.add_argument("--feedforward", metavar="NPY",
                   help="also write the reference's joint velocities (T-1, 7) here, as the q̇ of the reference too: "
                        "the plan for [control] feedforward_file (error-state MPC; SPEC's reference has q̇ = 0)")
    x = sub.add_parser("x0", parents=[common], help="print the start state (JSON) for [control] x0")
    x.add_argument("--steps", type=int, default=2, help=argparse.SUPPRESS)
    rep = sub.add_parser("report", parents=[common], help="score the closed loop of OUT/report.json, draw OUT/figure8.png")
    rep.add_argument("--out", required=True, help="the run's output folder (holds report.json)")
    rep.add_argument("--sim", default="arm0", help="the controlled simulator's id (default: %(default)s)")
    rep.add_argument("--no-plot", action="store_true", help="skip figure8.png")
    rep.add_argument("--no-error-state", action="store_true", help="skip the in-process error-state MPC row")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs a subcommand; returns the exit code (2: bad arguments or input)."""
    a = parser().parse_args(argv)
    if a.cmd == "report":
        try:
            entry = report(Path(a.out), a.sim, a.state, a.u_limit, plot=not a.no_plot, error_state=not a.no_error_state)
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
    if a.feedforward:
        plan, uff = plan_of(sim, task, a.u_limit)
        write_npy(a.out, plan)
        write_npy(a.feedforward, uff)
    else:
        write_npy(a.out, task.x)
    print(f"figure8 reference: {task.x.shape} to {a.out} (IK error <= {task.ik_error:.2e} m)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
