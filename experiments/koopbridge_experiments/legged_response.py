"""What limits a legged robot's learned feedback (issue 44 §1): the model's input response along
held-out references against the simulator's own, horizon by horizon, and its prediction error on
windows of different origins (the expert's, the MPC's own closed loops).

The input response. Along each reference the expert's recorded targets are replayed from its
first state on an in-process simulator built as the adapter is (so the states are the ones the
survival task starts from and visits); every ``--every`` steps, from the replay's state
``x_k`` (restored exactly: the simulator remembers its states), the next ``H`` recorded targets
``U = u_k .. u_{k+H-1}`` are applied with input ``i`` of the first one moved by ``±δ`` (central
differences; one-sided where a bound clips it). The simulator's response
``G_sim[h][:, i] = (x_{k+h}(U + δe_i) − x_{k+h}(U − δe_i)) / (2δ)`` is compared with the model's
``G_model[h]`` from ``KoopmanModel.predict`` with the same inputs, on two blocks: the joint
positions (what survival scores, rad per rad) and the whole state weighted by the model's
z-score (what the MPC's cost ``Q = I`` on the z-scored state sees). Per horizon ``h``: the
projection ``⟨G_model, G_sim⟩ / ‖G_sim‖²`` (1 = the same response, 0 = none, < 0 = the wrong
sign), the cosine and the norm ratio, pooled over every sample; the share of the simulator's joint
response that one response for every state explains (``1 − Σ‖G − Ḡ‖² / Σ‖G‖²``: a lifted-linear
model's ``P·A^(h−1)·B`` does not depend on the state, so this bounds its agreement); and the
nominal prediction error (the model's rollout of ``U`` against the simulator's, mean absolute
joint error in rad).

The prediction error by origin: for each ``--windows`` file (a dataset ``.npz``: the expert's
``test.npz``, a survival run's ``onpolicy/*.npz``), the model's open-loop rollout of each window
against its recorded states, the mean squared error on the z-scored state per step and the mean
absolute joint error at the last step.
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
from .legged_robots import ROBOTS, LeggedRobot, Reference, SetupError, references

__all__ = ["ResponseSample", "model_response", "prediction_by_origin", "response_along", "sim_response", "summarise", "main"]

#: Horizons reported in the table (the figure has every one).
SHOWN = (1, 2, 5, 10, 15)


class ResponseSample:
    """One point of a reference: the simulator's and the model's input responses ``(H, nx, nu)``
    and the two nominal rollouts ``(H, nx)`` from the state ``x``."""

    def __init__(self, ref: int, k: int, x: np.ndarray, sim: np.ndarray, model: np.ndarray, sim_nominal: np.ndarray, model_nominal: np.ndarray):
        self.ref, self.k, self.x = ref, k, x
        self.sim, self.model = sim, model
        self.sim_nominal, self.model_nominal = sim_nominal, model_nominal


def _perturbed(U: np.ndarray, i: int, delta: float, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``U`` with input ``i`` of its first row moved up and down by ``delta`` within the bounds,
    and the difference actually made (0 when both sides are clipped)."""
    up, down = U.copy(), U.copy()
    up[0, i] = min(U[0, i] + delta, hi[i])
    down[0, i] = max(U[0, i] - delta, lo[i])
    return up, down, float(up[0, i] - down[0, i])


def _rollout(sim: Any, x: np.ndarray, U: np.ndarray) -> np.ndarray:
    """The simulator's states ``x_1 .. x_H`` under ``U`` from the remembered state ``x`` (NaN
    rows after a step the simulator refuses)."""
    from koopbridge import KoopbridgeError

    sim.reset(x0=x)
    out = np.full((len(U), len(x)), np.nan)
    for t, u in enumerate(U):
        try:
            out[t] = sim.step(u)
        except KoopbridgeError:
            break
    return out


def sim_response(sim: Any, x: np.ndarray, U: np.ndarray, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's response ``(H, nx, nu)`` to the first input of ``U`` from the remembered
    state ``x`` (central differences of ``delta``, see the module docstring; NaN for an input the
    bounds pin), and its nominal rollout ``(H, nx)``."""
    H, nu = U.shape
    G = np.full((H, len(x), nu), np.nan)
    lo, hi = np.asarray(sim.u_lo, float), np.asarray(sim.u_hi, float)
    for i in range(nu):
        up, down, d = _perturbed(U, i, delta, lo, hi)
        if d <= 0:
            continue
        G[:, :, i] = (_rollout(sim, x, up) - _rollout(sim, x, down)) / d
    return G, _rollout(sim, x, U)


def model_response(model: Any, x: np.ndarray, U: np.ndarray, delta: float, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The model's response ``(H, nx, nu)`` and nominal rollout ``(H, nx)``, with the same
    perturbed inputs as ``sim_response``."""
    H, nu = U.shape

    def roll(V: np.ndarray) -> np.ndarray:
        p = np.asarray(model.predict(x, V), float)
        return p[-H:]  # predict may include x_0 as its first row

    G = np.full((H, len(x), nu), np.nan)
    for i in range(nu):
        up, down, d = _perturbed(U, i, delta, lo, hi)
        if d > 0:
            G[:, :, i] = (roll(up) - roll(down)) / d
    return G, roll(U)


def response_along(robot: LeggedRobot, model: Any, refs: Sequence[Reference], *, every: int, horizon: int, delta: float,
                   progress: bool = True) -> list[ResponseSample]:
    """The samples of every reference: the expert's targets replayed from its first state, a
    sample every ``every`` steps while the replay stays upright and the horizon fits."""
    sim = robot.simulator(None, 4096)
    fall = robot.fall()
    lo, hi = np.asarray(sim.u_lo, float), np.asarray(sim.u_hi, float)
    lay = robot.layout
    out: list[ResponseSample] = []
    for n, ref in enumerate(refs):
        x = np.asarray(sim.reset(x0=ref.x[0]), float)
        xs = [x]
        for k in range(ref.steps):
            x = np.asarray(sim.step(ref.u[k]), float)
            xs.append(x)
            if fall.fallen(x[lay.quat], float(x[lay.height])):
                break
        for k in range(0, min(len(xs) - 1, ref.steps - horizon), every):
            U = ref.u[k : k + horizon]
            G_sim, nom_sim = sim_response(sim, xs[k], U, delta)
            G_mod, nom_mod = model_response(model, xs[k], U, delta, lo, hi)
            out.append(ResponseSample(n, k, xs[k], G_sim, G_mod, nom_sim, nom_mod))
        if progress:
            print(f"legged_response: reference {n + 1}/{len(refs)}: {len(out)} samples", file=sys.stderr, flush=True)
    return out


def _agreement(Gm: np.ndarray, Gs: np.ndarray) -> dict[str, float]:
    """Projection, cosine and norm ratio of two stacks of responses (NaN entries dropped)."""
    ok = np.isfinite(Gm) & np.isfinite(Gs)
    m, s = Gm[ok], Gs[ok]
    ss, mm, ms = float(s @ s), float(m @ m), float(m @ s)
    if ss == 0 or mm == 0:
        return dict(projection=float("nan"), cosine=float("nan"), norm_ratio=float("nan"))
    return dict(projection=ms / ss, cosine=ms / np.sqrt(ss * mm), norm_ratio=float(np.sqrt(mm / ss)))


def summarise(samples: Sequence[ResponseSample], q: slice, x_scale: np.ndarray) -> dict[str, Any]:
    """Per horizon: the agreement on the joint block and on the whole z-scored state, the
    simulator's joint response size (rad per rad) and the nominal joint prediction error."""
    H = samples[0].sim.shape[0]
    w = (1.0 / x_scale)[None, :, None]
    rows = []
    for h in range(H):
        Gs = np.stack([s.sim[h] for s in samples])
        Gm = np.stack([s.model[h] for s in samples])
        nom = np.array([np.nanmean(np.abs(s.model_nominal[h, q] - s.sim_nominal[h, q])) for s in samples])
        joints = _agreement(Gm[:, q, :], Gs[:, q, :])
        whole = _agreement(Gm * w, Gs * w)
        # A linear lifted model's response P·A^(h-1)·B is the same at every state: the best any
        # can do is the mean response, which explains this share of the simulator's.
        Gq = Gs[:, q, :]
        mean = np.nanmean(Gq, axis=0, keepdims=True)
        constant_share = 1.0 - float(np.nansum((Gq - mean) ** 2) / np.nansum(Gq**2))
        rows.append(dict(h=h + 1, joints=joints, zscored_state=whole, constant_share_joints=constant_share,
                         sim_joint_gain=float(np.sqrt(np.nanmean(np.sum(Gs[:, q, :] ** 2, axis=(1, 2))))),
                         model_joint_gain=float(np.sqrt(np.nanmean(np.sum(Gm[:, q, :] ** 2, axis=(1, 2))))),
                         nominal_joint_error_rad=float(np.nanmean(nom))))
    return dict(samples=len(samples), horizons=rows)


def prediction_by_origin(model: Any, files: Sequence[str], q: slice, x_scale: np.ndarray, limit: int, seed: int = 0) -> dict[str, Any]:
    """The model's open-loop prediction error on the windows of each file (at most ``limit``
    windows each, drawn without replacement with ``seed``)."""
    out: dict[str, Any] = {}
    rng = np.random.default_rng(seed)
    for f in files:
        try:
            with np.load(f) as z:
                X, U = np.asarray(z["x"], float), np.asarray(z["u"], float)
        except (OSError, KeyError, ValueError) as e:
            raise SetupError(f"--windows {f}: {e}") from e
        if X.ndim != 3 or U.ndim != 3 or X.shape[2] != model.nx or U.shape[2] != model.nu:
            raise SetupError(f"--windows {f}: x {X.shape} / u {U.shape} do not fit the model's nx {model.nx} / nu {model.nu}")
        idx = rng.choice(len(X), size=min(limit, len(X)), replace=False) if len(X) else np.array([], int)
        per_step, last_joint = [], []
        for i in idx:
            T = U.shape[1]
            p = np.asarray(model.predict(X[i, 0], U[i]), float)[-T:]
            err = (p - X[i, 1:]) / x_scale
            per_step.append(np.mean(err**2, axis=1))
            last_joint.append(float(np.mean(np.abs(p[-1, q] - X[i, -1, q]))))
        out[f] = dict(windows=int(len(idx)), of=int(len(X)),
                      zscored_mse_per_step=np.mean(per_step, axis=0).round(6).tolist() if per_step else [],
                      zscored_mse=float(np.mean(per_step)) if per_step else float("nan"),
                      last_step_joint_error_rad=float(np.mean(last_joint)) if last_joint else float("nan"))
    return out


def _plot(path: Path, results: dict[str, Any]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(14, 4))
    for label, r in results.items():
        hs = [row["h"] for row in r["response"]["horizons"]]
        ax[0].plot(hs, [row["joints"]["projection"] for row in r["response"]["horizons"]], marker="o", label=f"{label} joints")
        ax[0].plot(hs, [row["zscored_state"]["projection"] for row in r["response"]["horizons"]], ls="--", label=f"{label} z-scored state")
        ax[1].plot(hs, [row["joints"]["cosine"] for row in r["response"]["horizons"]], marker="o", label=f"{label} joints")
        ax[1].plot(hs, [row["zscored_state"]["cosine"] for row in r["response"]["horizons"]], ls="--", label=f"{label} z-scored state")
        ax[2].plot(hs, [row["nominal_joint_error_rad"] for row in r["response"]["horizons"]], marker="o", label=label)
    first = next(iter(results.values()))["response"]["horizons"]
    ax[1].plot([row["h"] for row in first], [row["constant_share_joints"] for row in first], color="k", ls=":",
               label="share a state-independent response explains")
    ax[0].axhline(1, color="k", lw=0.5)
    ax[0].axhline(0, color="k", lw=0.5)
    ax[0].set(title="input response: projection on the simulator's", xlabel="steps after the input (h)", ylabel="⟨G_model, G_sim⟩ / ‖G_sim‖²")
    ax[1].set(title="input response: cosine", xlabel="h", ylabel="cosine / share")
    ax[2].set(title="nominal prediction error along the replay", xlabel="h", ylabel="mean |q_model − q_sim| (rad)")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.legged_response", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="example: python -m koopbridge_experiments.legged_response --robot go2 --model models/go2-both "
                                "--references 10 --windows data/go2/test.npz --windows results/go2-survival/onpolicy/go2-both.npz --out OUT")
    p.add_argument("--robot", choices=sorted(ROBOTS), default="go2", help="the legged robot (default: %(default)s)")
    p.add_argument("--model", action="append", required=True, metavar="DIR", help="a Koopman model folder (repeatable)")
    p.add_argument("--references", type=int, default=10, help="held-out references (seed 90042 as the survival task; default: %(default)s)")
    p.add_argument("--steps", type=int, help="reference length (default: the robot's survival cap)")
    p.add_argument("--every", type=int, default=25, help="a sample every this many steps of a reference (default: %(default)s)")
    p.add_argument("--horizon", type=int, default=15, help="steps after the input (default: %(default)s, the MPC's H)")
    p.add_argument("--delta", type=float, default=0.05, help="central-difference step on a joint target, rad (default: %(default)s)")
    p.add_argument("--windows", action="append", default=[], metavar="NPZ", help="a dataset .npz to measure the prediction error on (repeatable)")
    p.add_argument("--windows-limit", type=int, default=500, help="windows drawn from each --windows file (default: %(default)s)")
    p.add_argument("--out", required=True, help="output folder (report.json, response.png)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the command line; 2 on bad input."""
    from koopbridge import KoopmanModel

    a = parser().parse_args(argv)
    robot = ROBOTS[a.robot]
    if a.every < 1 or a.horizon < 1 or not (np.isfinite(a.delta) and a.delta > 0) or a.references < 1:
        print("legged_response: --every, --horizon, --references must be >= 1 and --delta > 0", file=sys.stderr)
        return 2
    try:
        models = []
        for d in a.model:
            try:
                models.append((Path(d).name, Path(d).resolve(), KoopmanModel.load(d)))
            except Exception as e:  # noqa: BLE001 - the loader's own error, named
                raise SetupError(f"--model {d}: not a Koopman model folder ({e})") from e
        for label, _, m in models:
            if (m.nx, m.nu) != (robot.nx, robot.nu):
                raise SetupError(f"--model {label} is {m.nx}/{m.nu}-D; the {robot.title} is {robot.nx}/{robot.nu}-D")
        refs = references(robot, a.references, a.steps or robot.steps)
        results: dict[str, Any] = {}
        for label, path, m in models:
            norm = m.normalisation
            scale = np.asarray(norm["x_std"], float) if norm else np.concatenate([r.x for r in refs]).std(axis=0)
            scale = np.maximum(scale, 1e-8)
            samples = response_along(robot, m, refs, every=a.every, horizon=a.horizon, delta=a.delta)
            if not samples:
                raise SetupError("no sample: every replay fell before the horizon fits")
            results[label] = dict(dir=str(path), response=summarise(samples, robot.layout.q, scale),
                                  prediction=prediction_by_origin(m, a.windows, robot.layout.q, scale, a.windows_limit))
    except SetupError as e:
        print(f"legged_response: {e}", file=sys.stderr)
        return 2
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    report = dict(robot=robot.name, references=a.references, every=a.every, horizon=a.horizon, delta=a.delta, models=results)
    write_atomic(str(out / "report.json"), lambda f: f.write(json.dumps(report, indent=2).encode()))  # type: ignore[attr-defined]
    _plot(out / "response.png", results)
    for label, r in results.items():
        print(f"{label}: h  joints proj/cos/ratio   z-state proj/cos   nominal joint err (rad)   constant share")
        for row in r["response"]["horizons"]:
            if row["h"] in SHOWN:
                j, z = row["joints"], row["zscored_state"]
                print(f"  {row['h']:2d}  {j['projection']:+.3f} {j['cosine']:+.3f} {j['norm_ratio']:.3f}   "
                      f"{z['projection']:+.3f} {z['cosine']:+.3f}   {row['nominal_joint_error_rad']:.4f}   {row['constant_share_joints']:.3f}")
        for f, p in r["prediction"].items():
            print(f"  windows {f}: z-scored MSE {p['zscored_mse']:.4f}, last-step joint error {p['last_step_joint_error_rad']:.4f} rad "
                  f"({p['windows']} of {p['of']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
