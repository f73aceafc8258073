"""The classical yardstick for balancing a Gymnasium MuJoCo pendulum: LQR on the simulator's own
linearisation at upright (central finite differences of one step), from given tilts.

The learned controllers of ``scenarios/gym-inverted-double-pendulum.toml`` and
``gym-inverted-pendulum.toml`` are measured against it (BENCHMARKS.md, "An unstable system on the
first day"): the same starts (every hinge tilted by the same angle, the cart at 0), the same goal
as the scenario engine's (``GoalSpec``: |angle| ≤ 0.05, every other component ≤ 0.1, held 50
steps), the same input bounds. It steps ``GymSimulator`` directly: a baseline that needs no model,
not a controller of the bridge.

    python -m koopbridge_experiments.gym_lqr --env InvertedDoublePendulum-v5 \\
        --q 1 10 10 0.1 0.1 0.1 --r 1 --tilts 0.02 0.05 0.1 0.2 0.3

prints, per tilt, the step the goal was reached from (or the step the environment ended the episode: a pole fell)
and the largest tilt balanced (``--json FILE`` writes them). Also: the open loop's eigenvalue of
largest modulus per step (how unstable the plant is where it is controlled) and |K|'s largest
gain (what a unit of tilt asks of the input).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from koopbridge.adapters.gym.sim import GymSimulator

#: The scenario engine's goal (koopman::mpc::metrics::GoalSpec::default).
ANGLE_TOL, RATE_TOL, HOLD = 0.05, 0.1, 50


def linearise(sim: GymSimulator, x_eq: np.ndarray, u_eq: np.ndarray, eps: float = 1e-5) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of ``x⁺ = f(x, u)`` at ``(x_eq, u_eq)`` by central differences, each from a fresh
    ``reset(x0=...)``."""
    nx, nu = len(x_eq), len(u_eq)

    def f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        sim.reset(x0=x)
        return np.asarray(sim.step(u), dtype=np.float64)

    a = np.zeros((nx, nx))
    b = np.zeros((nx, nu))
    for i in range(nx):
        d = np.zeros(nx)
        d[i] = eps
        a[:, i] = (f(x_eq + d, u_eq) - f(x_eq - d, u_eq)) / (2 * eps)
    for j in range(nu):
        d = np.zeros(nu)
        d[j] = eps
        b[:, j] = (f(x_eq, u_eq + d) - f(x_eq, u_eq - d)) / (2 * eps)
    return a, b


def dlqr(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray, iterations: int = 100_000, tol: float = 1e-12) -> np.ndarray:
    """The infinite-horizon discrete LQR gain ``K`` (``u = -K x``) by Riccati iteration to a fixed
    point; raises ``RuntimeError`` when it does not converge (an unstabilisable pair)."""
    p = q.copy()
    for _ in range(iterations):
        bp = b.T @ p
        k = np.linalg.solve(r + bp @ b, bp @ a)
        p_next = q + a.T @ p @ (a - b @ k)
        p_next = 0.5 * (p_next + p_next.T)
        if np.max(np.abs(p_next - p)) <= tol * max(1.0, np.max(np.abs(p))):
            return k
        p = p_next
    raise RuntimeError("the Riccati iteration did not converge: (A, B) is not stabilisable here")


def balance(sim: GymSimulator, k: np.ndarray, x0: np.ndarray, steps: int, angles: Sequence[int]) -> dict[str, Any]:
    """One LQR run from ``x0`` (``u = clip(-K x)`` to the simulator's bounds): the goal step
    (engine's definition), the step the environment terminated the episode (a fall), the final state and the share of steps at a bound."""
    x = np.asarray(sim.reset(x0=x0), dtype=np.float64)
    xs = [x]
    at_bound = 0
    fell = None
    for t in range(steps):
        u = np.clip(-k @ x, sim.u_lo, sim.u_hi)
        at_bound += int(np.any((u <= sim.u_lo) | (u >= sim.u_hi)))
        x = np.asarray(sim.step(u), dtype=np.float64)
        xs.append(x)
        if not np.all(np.isfinite(x)) or sim.step_status().get("terminated", False):
            fell = t + 1
            break
    tol = np.array([ANGLE_TOL if i in angles else RATE_TOL for i in range(len(x0))])
    run, goal = 0, None
    for i, xi in enumerate(xs):
        run = run + 1 if np.all(np.abs(xi) <= tol) else 0
        if run >= HOLD:
            goal = i + 1 - HOLD
            break
    return {"goal_step": goal, "fell_step": fell, "final_state": xs[-1].tolist(), "at_bound_share": at_bound / max(1, len(xs) - 1)}


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="InvertedDoublePendulum-v5", help="a Gymnasium MuJoCo env with a cart (slider) and hinged poles (default %(default)s)")
    p.add_argument("--q", type=float, nargs="+", help="diagonal of Q, one per state (default: 1 on the cart, 10 per hinge, 0.1 per velocity)")
    p.add_argument("--r", type=float, default=1.0, help="R = r·I (default %(default)s)")
    p.add_argument("--tilts", type=float, nargs="+", default=[0.02, 0.05, 0.1, 0.2, 0.3], help="every hinge tilted by this (rad), each a run (default %(default)s)")
    p.add_argument("--opposite", action="store_true", help="tilt the second hinge the other way (the issue's 'opposite tilts')")
    p.add_argument("--steps", type=int, default=300, help="steps per run (default %(default)s)")
    p.add_argument("--json", help="write the results here")
    a = p.parse_args(argv)

    sim = GymSimulator(a.env, state="qpos,qvel")
    info = sim.info()
    nx, nu = info.nx, info.nu
    angles = list(info.get("angles") or [i for i, n in enumerate(info["state_names"]) if "hinge" in n and not n.endswith("_vel")])
    q = np.diag(a.q) if a.q else np.diag([10.0 if i in angles else (1.0 if i < nx // 2 else 0.1) for i in range(nx)])
    if q.shape != (nx, nx):
        p.error(f"--q needs {nx} values (the states: {', '.join(info['state_names'])})")
    x_eq, u_eq = np.zeros(nx), np.zeros(nu)
    a_mat, b_mat = linearise(sim, x_eq, u_eq)
    rho = float(np.max(np.abs(np.linalg.eigvals(a_mat))))
    k = dlqr(a_mat, b_mat, q, a.r * np.eye(nu))
    closed = float(np.max(np.abs(np.linalg.eigvals(a_mat - b_mat @ k))))
    print(f"{a.env}: dt {sim.dt} s, open-loop |λ|max {rho:.3f} per step, closed-loop (LQR) {closed:.3f}; largest |K| {np.max(np.abs(k)):.2f}; input bounds {sim.u_lo.tolist()}..{sim.u_hi.tolist()}")
    runs = []
    for tilt in a.tilts:
        x0 = np.zeros(nx)
        for n, i in enumerate(angles):
            x0[i] = -tilt if (a.opposite and n % 2 == 1) else tilt
        r = balance(sim, k, x0, a.steps, angles)
        r["tilt"] = tilt
        runs.append(r)
        what = f"goal from step {r['goal_step']}" if r["goal_step"] is not None else (f"fell at step {r['fell_step']}" if r["fell_step"] else "goal not reached")
        print(f"  tilt {tilt:+.3f} rad: {what}; {100 * r['at_bound_share']:.0f} % of steps at an input bound")
    balanced = [r["tilt"] for r in runs if r["goal_step"] is not None]
    largest = max(balanced) if balanced else None
    print(f"largest tilt balanced: {largest}")
    sim.close()
    if a.json:
        out = {"env": a.env, "q": np.diag(q).tolist(), "r": a.r, "open_loop_rho": rho, "closed_loop_rho": closed, "k": k.tolist(), "runs": runs, "largest_tilt_balanced": largest}
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
