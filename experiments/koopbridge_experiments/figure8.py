"""The Franka figure-8 tracked through the bridge (SPEC "Control"): the MuJoCo adapter served in
lockstep in a child process, the Rust MPC service (``koopbridge serve mpc models``) deciding
every step, configured through ``Client.configure_mpc``; compared with zero input and a
joint-space P controller over the same adapter. Writes ``report.json`` and ``figure8.png``.

    python -m koopbridge_experiments.figure8 --model models/franka-edmd --out results/franka-figure8 [--steps 3001]

``--model DIR`` is a trained model folder; its parent is the MPC service's model store and its
name (``[a-z0-9_-]``) the model it loads. The service picks the controller by the model's kind:
Koopman MPC for ``koopman``/``edmd``, random-shooting MPC (1000 sequences per step, the paper's
NNDM baseline) for ``nndm``.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from koopbridge import BridgeTimeout, Client
from koopbridge.cli_path import koopbridge_cli
from koopbridge.testing import listening_client

from .dataset_npz import write_atomic
from .figure8_ref import SKIP, Figure8, joint_p_command, references, tracking_error

__all__ = ["Run", "main", "parser", "run_controller", "summarise"]

SIM_ID = "arm0"
MPC_ID = "fig8"
NAME = re.compile(r"^[a-z0-9_-]+$")


class Run:
    """One controller's run: end-effector path ``ee`` ``(n, 3)``, states ``x``, inputs ``u``,
    solve times inside the service and round trips (s, MPC only)."""

    def __init__(self, name: str, x: np.ndarray, u: np.ndarray, solve_s: list[float], round_trip_s: list[float], wall_s: float, statuses: dict[str, int]):
        self.name, self.x, self.u = name, x, u
        self.ee = x[:, :3]
        self.solve_s, self.round_trip_s, self.wall_s, self.statuses = solve_s, round_trip_s, wall_s, statuses


def run_controller(c: Client, task: Figure8, kind: str, *, model: str | None = None, horizon: int = 15,
                   noise: float = 0.01, seed: int = 0, p_gain: float = 5.0, u_limit: float = 0.3) -> Run:
    """Resets the adapter to the task's start and runs ``kind`` (``mpc``, ``zero`` or ``p``)
    for ``len(task.x) − 1`` lockstep steps. The MPC sees the end-effector position with
    N(0, ``noise``²) added (SPEC); the P controller uses q, which carries no noise."""
    n = len(task.x)
    rng = np.random.default_rng(seed)
    x = np.asarray(c.reset(SIM_ID, x0=task.x0))
    xs, us = [x], []
    solve_s: list[float] = []
    rt_s: list[float] = []
    statuses: dict[str, int] = {}
    t0 = time.perf_counter()
    for k in range(n - 1):
        if kind == "mpc":
            obs = x.copy()
            obs[:3] += rng.normal(0.0, noise, 3)
            t = time.perf_counter()
            sol = c.solve(MPC_ID, obs, task.reference_window(k, horizon), model=model or "", nu=7)
            rt_s.append(time.perf_counter() - t)
            solve_s.append(float(sol["solve_time"]))
            statuses[str(sol["status"])] = statuses.get(str(sol["status"]), 0) + 1
            u = np.asarray(sol["u"])[0]
        elif kind == "zero":
            u = np.zeros(7)
        elif kind == "p":
            u = joint_p_command(x[3:10], task.q[k + 1], p_gain, u_limit)
        else:
            raise ValueError(f"controller {kind!r}: expected mpc, zero or p")
        x = np.asarray(c.step(SIM_ID, u)[2])
        xs.append(x)
        us.append(u)
    return Run(kind, np.array(xs), np.array(us), solve_s, rt_s, time.perf_counter() - t0, statuses)


def _stats_us(v: list[float]) -> dict[str, float] | None:
    if not v:
        return None
    a = np.array(v) * 1e6
    return dict(median_us=round(float(np.median(a)), 1), p99_us=round(float(np.percentile(a, 99)), 1), max_us=round(float(a.max()), 1))


def summarise(run: Run, task: Figure8, u_limit: float = 0.3) -> dict[str, Any]:
    """The report entry of one run: tracking error, steps, timings, saturation (commands at
    ±``u_limit``)."""
    sat = float(np.mean(np.abs(run.u) >= u_limit - 1e-9)) if len(run.u) else 0.0
    return dict(
        error=tracking_error(run.ee, task.targets),
        steps=len(run.u),
        wall_s=round(run.wall_s, 3),
        steps_per_s=round(len(run.u) / run.wall_s, 1) if run.wall_s > 0 else None,
        solve=_stats_us(run.solve_s),
        round_trip=_stats_us(run.round_trip_s),
        statuses=run.statuses or None,
        saturated_fraction=round(sat, 4),
    )


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m koopbridge_experiments.figure8``."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.figure8", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", required=True, help="trained model folder (its parent is used as the model store)")
    p.add_argument("--out", default="results/franka-figure8", help="folder for report.json and figure8.png (default: %(default)s)")
    p.add_argument("--steps", type=int, default=3001, help="points of the figure-8, k = 0..steps-1 (SPEC: 3001)")
    p.add_argument("--horizon", type=int, default=15, help="MPC horizon H (default: %(default)s)")
    p.add_argument("--noise", type=float, default=0.01, help="σ of the noise on the observed ee position (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default: %(default)s)")
    p.add_argument("--q-weights", help="diagonal of Q, comma separated (default: identity, SPEC)")
    p.add_argument("--baselines", default="zero,p", help="baselines to run besides the MPC: zero, p, or none (default: %(default)s)")
    p.add_argument("--p-gain", type=float, default=5.0, help="gain of the joint-space P baseline, 1/s (default: %(default)s)")
    p.add_argument("--u-limit", type=float, default=0.3, help="command clip of the adapter, the MPC bounds and the P baseline, rad/s "
                   "(default: %(default)s, SPEC; larger values show what the clip costs)")
    p.add_argument("--no-plot", action="store_true", help="skip figure8.png")
    p.add_argument("--session", help="koopbridge session id (default: a fresh one)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the task; returns the exit code (2: bad arguments or set-up)."""
    a = parser().parse_args(argv)
    model_dir = Path(a.model).resolve()
    name = model_dir.name
    if not (model_dir / "config.json").is_file():
        print(f"figure8: {model_dir} is not a model folder (no config.json)", file=sys.stderr)
        return 2
    if not NAME.match(name):
        print(f"figure8: model folder name {name!r} must match [a-z0-9_-]+ (it is the model's name in the store)", file=sys.stderr)
        return 2
    if a.steps <= SKIP + 1 or a.horizon < 1:
        print(f"figure8: --steps must exceed {SKIP + 1} and --horizon be >= 1", file=sys.stderr)
        return 2
    baselines = [b for b in a.baselines.split(",") if b and b != "none"]
    if any(b not in ("zero", "p") for b in baselines):
        print(f"figure8: --baselines {a.baselines!r}: expected zero, p or none", file=sys.stderr)
        return 2
    from koopbridge.adapters.mujoco.sim import FrankaSimulator

    sim = FrankaSimulator()
    t = time.perf_counter()
    task = references(sim, a.steps)
    ik_s = time.perf_counter() - t
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    session = a.session or "f8" + uuid.uuid4().hex[:10]
    client, ep = listening_client(session)
    state = Path(tempfile.mkdtemp(prefix="figure8-state-"))
    adapter_cmd = [sys.executable, "-m", "koopbridge.adapters.mujoco", "--session", session, "--id", SIM_ID, "--connect", ep,
                   "--u-limit", repr(a.u_limit)]
    serve_cmd = [koopbridge_cli(), "serve", "mpc", "models", "--session", session, "--id", MPC_ID, "--store", str(model_dir.parent),
                 "--state-dir", str(state), "--connect", ep]
    logs = {k: open(out / f"{k}.log", "wb") for k in ("adapter", "services")}
    procs = [subprocess.Popen(cmd, stdout=logs[k], stderr=subprocess.STDOUT, stdin=subprocess.PIPE)
             for k, cmd in (("adapter", adapter_cmd), ("services", serve_cmd))]
    try:
        with client as c:
            c.connect_sim(SIM_ID, timeout=60)
            mpc_cfg: dict[str, Any] = dict(horizon=a.horizon, u_min=[-a.u_limit] * 7, u_max=[a.u_limit] * 7)
            if a.q_weights:
                mpc_cfg["q"] = [float(v) for v in a.q_weights.split(",")]
            deadline = time.monotonic() + 60
            while True:
                try:
                    conf = c.configure_mpc(MPC_ID, name, **mpc_cfg)
                    break
                except BridgeTimeout:
                    if time.monotonic() > deadline:
                        raise
            runs = [run_controller(c, task, "mpc", model=name, horizon=a.horizon, noise=a.noise, seed=a.seed)]
            for b in baselines:
                runs.append(run_controller(c, task, b, p_gain=a.p_gain, u_limit=a.u_limit))
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        for f in logs.values():
            f.close()
        shutil.rmtree(state, ignore_errors=True)
    report = dict(
        task=dict(steps=a.steps, skip=SKIP, noise=a.noise, seed=a.seed, horizon=a.horizon, q=mpc_cfg.get("q", "identity"),
                  u_limit=a.u_limit, ik_max_error_m=task.ik_error, ik_s=round(ik_s, 3),
                  max_ref_joint_speed=[round(float(v), 4) for v in np.abs(np.diff(task.q, axis=0)).max(axis=0) / 0.02]),
        model=dict(dir=str(model_dir), name=name, configure=conf),
        controllers={r.name: summarise(r, task, a.u_limit) for r in runs},
    )
    write_atomic(str(out / "report.json"), lambda f: f.write(json.dumps(report, indent=2).encode()))  # type: ignore[attr-defined]
    arrays = dict(targets=task.targets, **{f"x_{r.name}": r.x for r in runs}, **{f"u_{r.name}": r.u for r in runs})
    write_atomic(str(out / "paths.npz"), lambda f: np.savez(f, **arrays))
    if not a.no_plot:
        from .figure8_plot import plot

        plot(str(out / "figure8.png"), task, runs)
    print(json.dumps({k: v["error"] for k, v in report["controllers"].items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
