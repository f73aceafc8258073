"""The Kinova steps of ``scenarios/kinova-drake.toml``: ``reference`` (a ``before-control`` hook)
asks the scenario's Drake planner over Zenoh for trajectories to held-out goals (goals of no
collection session) and writes them as the ``(T, 14)`` ``[q, q̇]`` reference that ``[control]
reference_file`` reads; ``report`` (an ``after-control`` hook) scores every closed loop the engine
ran on the arm — one row per labelled ``[[control]]`` entry: the error-state MPC about the plan
with and without the position loop, the planner's open-loop feed-forward, the feed-forward with
LQR on the lifted model (the MPC service's law ``lqr``), and the same on an arm whose actuators
realise only a fraction of each command (rows labelled ``…-mismatch``, the perturbation
``command_gain``) — adds the arm held still, writes the result to ``report.json`` and draws
``kinova.png``. No closed loop runs here.

    python -m koopbridge_experiments.kinova_scenario reference --out OUT --session S --connect EP [--goals 2]
    python -m koopbridge_experiments.kinova_scenario report --out OUT [--sim gen3]

``reference`` writes ``OUT/kinova-reference.npy`` (row k: the planned state at step k, 1 kHz, the
plans chained from the upright arm with a hold at each goal), ``OUT/kinova-feedforward.npy``
(row k: the planned velocity applied at step k) and ``OUT/kinova-plans.json`` (goals, their
seeds, the planner's pass reports).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .figure8_scenario import rows_of, write_npy
from .run_report import update_report

__all__ = ["held_out_goals", "main", "parser", "plan_reference", "tracking_errors"]

#: Goal sessions of the reference: far above any collection session of ``drake_collect``
#: (sessions count from 0 per split), so no goal was used for training, validation or test.
HELD_OUT_SESSION = 900
REFERENCE, FEEDFORWARD, PLANS = "kinova-reference.npy", "kinova-feedforward.npy", "kinova-plans.json"


def held_out_goals(seed: int, n: int, planner: Any) -> list[tuple[int, np.ndarray]]:
    """``n`` collision-free goals (2 cm margin, as the collection draws them) with their seeds:
    goal i from ``goal_seed(seed, "test", HELD_OUT_SESSION + i)``."""
    from koopbridge.adapters.drake.collect import goal_seed
    from koopbridge.adapters.drake.plan import random_goals

    out = []
    for i in range(n):
        s = goal_seed(seed, "test", HELD_OUT_SESSION + i)
        out.append((s, random_goals(s, 1, planner=planner, margin=0.02)[0]))
    return out


def plan_reference(ask: Any, goals: Sequence[tuple[int, np.ndarray]], dt: float, hold_s: float, q0: np.ndarray) -> dict[str, Any]:
    """Chains plans from ``q0`` through ``goals`` (``ask(start, goal, dt) -> reply dict`` or an
    exception with ``code == "infeasible"``: that goal is skipped), each followed by ``hold_s``
    at rest. Returns ``x`` ``(T, 14)``, ``ff`` ``(T - 1, 7)`` and the plans' records."""
    hold = int(round(hold_s / dt))
    xs, ffs, plans = [np.r_[q0, np.zeros(7)][None, :]], [], []
    start = np.asarray(q0, float)
    for seed, goal in goals:
        rec: dict[str, Any] = dict(goal=goal.tolist(), goal_seed=seed, start=start.tolist())
        try:
            r = ask(start.tolist(), goal.tolist(), dt)
        except Exception as e:  # noqa: BLE001 - only the planner's typed refusal is expected
            if getattr(e, "code", None) != "infeasible":
                raise
            rec["error"] = str(e)
            plans.append(rec)
            continue
        q, qd = np.asarray(r["q"], float), np.asarray(r["qd"], float)
        xs.append(np.c_[q, qd][1:])
        ffs.append(qd[:-1])
        xs.append(np.tile(np.r_[q[-1], np.zeros(7)], (hold, 1)))
        ffs.append(np.zeros((hold, 7)))
        rec.update(duration=r["duration"], steps=len(q) - 1, passes=r["passes"])
        plans.append(rec)
        start = q[-1]
    if not ffs:
        raise ValueError(f"the planner found no trajectory to any of the {len(goals)} goals")
    return dict(x=np.concatenate(xs), ff=np.concatenate(ffs), plans=plans)


def _reference(a: argparse.Namespace) -> int:
    from koopbridge import BridgeTimeout, Client, RemoteError
    from koopbridge.adapters.drake.plan import Gen3Planner

    out = Path(a.out)
    goals = held_out_goals(a.seed, a.goals, Gen3Planner())
    key = f"planner/{a.planner}/plan"
    with Client(session=a.session, connect=a.connect or None) as c:

        def ask(start: list[float], goal: list[float], dt: float) -> dict[str, Any]:
            body = json.dumps(dict(start=start, goal=goal, dt=dt)).encode()
            # `busy` (another plan running): retry for up to a minute. A query that ends at once
            # without a reply found no route to the planner yet (this fresh session has not yet
            # learnt the planner's queryable): retry that for up to 15 s.
            unrouted_until = time.monotonic() + 15.0
            for _ in range(600):
                sent = time.monotonic()
                try:
                    return json.loads(c.query(key, body, timeout=60.0))
                except RemoteError as e:
                    if e.code != "busy":
                        raise
                except BridgeTimeout:
                    if time.monotonic() - sent > 1.0 or time.monotonic() > unrouted_until:
                        raise
                time.sleep(0.1)
            raise RuntimeError(f"planner {a.planner!r} stayed busy for a minute")

        ref = plan_reference(ask, goals, a.dt, a.hold, np.zeros(7))
    write_npy(str(out / REFERENCE), ref["x"])
    write_npy(str(out / FEEDFORWARD), ref["ff"])
    meta = dict(seed=a.seed, sessions=f"test split, goal sessions {HELD_OUT_SESSION}..{HELD_OUT_SESSION + a.goals - 1}",
                dt=a.dt, hold_s=a.hold, steps=len(ref["ff"]), plans=ref["plans"])
    from .dataset_npz import write_atomic

    write_atomic(str(out / PLANS), lambda f: f.write(json.dumps(meta, indent=1).encode()))  # type: ignore[attr-defined]
    ok = sum("error" not in p for p in ref["plans"])
    print(f"kinova reference: {ok}/{len(goals)} plans, {len(ref['ff'])} steps to {out / REFERENCE}", file=sys.stderr)
    return 0


def tracking_errors(x: np.ndarray, ref: np.ndarray) -> dict[str, Any]:
    """Joint tracking RMS over every step and joint, per joint, and the final error (largest
    joint deviation at the last step), rad."""
    e = x[:, :7] - ref[: len(x), :7]
    return dict(rms_rad=float(np.sqrt(np.mean(e**2))), rms_per_joint_rad=np.sqrt(np.mean(e**2, axis=0)).round(6).tolist(),
                final_rad=float(np.max(np.abs(e[-1]))))


def _padded(a: np.ndarray, n: int, fill: np.ndarray | None = None) -> np.ndarray:
    """``a`` cut or extended to ``n`` rows (the last row repeated, or ``fill``)."""
    if len(a) >= n:
        return a[:n]
    tail = np.tile(a[-1] if fill is None else fill, (n - len(a), 1))
    return np.concatenate([a, tail])


#: The label suffix of the rows run on the mismatched arm (``perturbation = { command_gain = g }``).
MISMATCH = "-mismatch"


def _report(a: argparse.Namespace) -> int:
    out = Path(a.out)
    rep_path = out / "report.json"
    rows = rows_of(json.loads(rep_path.read_text()), a.sim)
    nominal = {k: v for k, v in rows.items() if not k.endswith(MISMATCH)}
    mismatched = {k[: -len(MISMATCH)]: v for k, v in rows.items() if k.endswith(MISMATCH)}
    through_service = next(iter(nominal))
    ctrl = nominal[through_service]
    steps = len(ctrl["u"])
    ref = _padded(np.load(out / REFERENCE), steps + 1)
    # Every row is the engine's (one labelled [[control]] entry each; LQR on the lifted model is
    # the MPC service's law `lqr`).
    runs = {k: np.asarray(v["x"], float) for k, v in nominal.items()}
    disturbed, dis, gain = None, {}, 1.0
    if mismatched:
        gains = {float((v.get("perturbation") or {}).get("command_gain") or 1.0) for v in mismatched.values()}
        if len(gains) != 1 or gains == {1.0}:
            raise ValueError(f"the rows labelled …{MISMATCH} must share one perturbation command_gain ≠ 1, got {sorted(gains)}")
        (gain,) = gains
        dis = {k: np.asarray(v["x"], float) for k, v in mismatched.items()}
        disturbed = dict(command_gain=gain, controllers={k: tracking_errors(v, ref) for k, v in dis.items()})
    lqr_rows = [v for v in nominal.values() if (v.get("mpc") or {}).get("law") == "lqr"]
    entry: dict[str, Any] = dict(
        steps=steps, dt=ctrl["dt"],
        metric="joint tracking error x[:7] - planned q over every step: RMS (all joints, per joint) and final (max |.| at the last step), rad",
        controllers={k: tracking_errors(v, ref) for k, v in runs.items()},
        # The floor every controller must beat: the arm left at its start (it holds to 1e-6 rad).
        hold_still=tracking_errors(np.tile(ref[0], (steps + 1, 1)), ref),
        lqr=dict(q=lqr_rows[0]["mpc"]["q"], r=lqr_rows[0]["mpc"]["r"],
                 law="u = qd_plan,k - K (phi(x_k) - phi(x_ref,k)), clipped to the velocity limits (the MPC service's law lqr)")
        if lqr_rows else None,
        through_service=through_service,
        position_loop=ctrl.get("position_loop"),
        mpc=dict(error_state=bool(ctrl.get("error_state")), settings=ctrl.get("mpc"), solve_median_us=ctrl.get("solve_median_us"),
                 round_trip_median_us=ctrl.get("solve_round_trip_median_us"),
                 not_solved=ctrl.get("not_solved")),
        disturbed=disturbed,
        plans=json.loads((out / PLANS).read_text())["plans"] if (out / PLANS).exists() else None,
        plot=None if a.no_plot else "kinova.png",
    )
    if not a.no_plot:
        _plot(out / "kinova.png", ref, runs, through_service, ctrl["dt"], dis if disturbed else None, gain)
    update_report(rep_path, "kinova", entry)
    table = dict(entry["controllers"], **{"hold-still": entry["hold_still"]})
    if disturbed:
        table.update({f"{k} (gain {gain:g})": v for k, v in disturbed["controllers"].items()})
    print(json.dumps({k: (round(v["rms_rad"], 6), round(v["final_rad"], 6)) for k, v in table.items()}))
    return 0


def _plot(path: Path, ref: np.ndarray, runs: dict[str, np.ndarray], shown: str, dt: float,
          disturbed: dict[str, np.ndarray] | None = None, gain: float = 1.0) -> None:
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .dataset_npz import write_atomic

    t = dt * np.arange(len(ref))
    fig, axes = plt.subplots(1, 3 if disturbed else 2, figsize=(19 if disturbed else 13, 5))
    ax1, ax2 = axes[0], axes[1]
    for j in range(7):
        line = ax1.plot(t, ref[:, j], "--", lw=1.2)[0]
        ax1.plot(t, runs[shown][:, j], "-", lw=0.9, color=line.get_color(), label=f"q{j + 1}")
    ax1.set_title(f"planned (dashed) vs executed (solid):\n{shown}, through the bridge", fontsize=10)
    ax1.set_xlabel("time (s)")
    ax1.set_ylabel("joint angle (rad)")
    ax1.legend(fontsize=7, ncol=2)
    # One colour per controller in both error panels.
    names = list(dict.fromkeys([*runs, *(disturbed or {})]))
    colour = {n: f"C{i}" for i, n in enumerate(names)}
    for name, x in runs.items():
        ax2.semilogy(t, np.maximum(np.linalg.norm(x[:, :7] - ref[:, :7], axis=1), 1e-9), lw=1, label=name, color=colour[name])
    ax2.set_title("joint tracking error |q - q_plan|")
    ax2.set_xlabel("time (s)")
    ax2.set_ylabel("rad")
    ax2.legend(fontsize=8)
    if disturbed:
        ax3 = axes[2]
        for name, x in disturbed.items():
            ax3.semilogy(t, np.maximum(np.linalg.norm(x[:, :7] - ref[:, :7], axis=1), 1e-9), lw=1, label=name, color=colour[name])
        ax3.set_title(f"the same on an arm realising {gain:g} x each command")
        ax3.set_xlabel("time (s)")
        ax3.set_ylabel("rad")
        ax3.legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    write_atomic(str(path), lambda f: f.write(buf.getvalue()))  # type: ignore[attr-defined]


def parser() -> argparse.ArgumentParser:
    """The command line (subcommands ``reference`` and ``report``)."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.kinova_scenario", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("reference", help="plan held-out goals through the planner, write the reference")
    r.add_argument("--out", required=True, help="the run's output folder")
    r.add_argument("--session", required=True, help="the run's koopbridge session")
    r.add_argument("--connect", action="append", default=[], help="a Zenoh endpoint of the run (repeatable)")
    r.add_argument("--planner", default="planner0", help="the planner's id (default: %(default)s)")
    r.add_argument("--goals", type=int, default=2, help="held-out goals, planned in a chain from the upright arm (default: %(default)s)")
    r.add_argument("--seed", type=int, default=42, help="the data seed (goal seeds derive from it; default: %(default)s)")
    r.add_argument("--dt", type=float, default=0.001, help="the simulator's dt, s (default: %(default)s)")
    r.add_argument("--hold", type=float, default=0.2, help="seconds at rest at each goal (default: %(default)s)")
    rep = sub.add_parser("report", help="score OUT/report.json's closed loops and the arm held still, draw OUT/kinova.png")
    rep.add_argument("--out", required=True, help="the run's output folder")
    rep.add_argument("--sim", default="gen3", help="the controlled simulator's id (default: %(default)s)")
    rep.add_argument("--no-plot", action="store_true", help="skip kinova.png")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs a subcommand; returns the exit code (2: bad arguments or input)."""
    a = parser().parse_args(argv)
    try:
        return _reference(a) if a.cmd == "reference" else _report(a)
    except (OSError, KeyError, ValueError) as e:
        print(f"kinova_scenario {a.cmd}: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
