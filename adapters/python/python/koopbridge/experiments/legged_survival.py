"""A legged robot's tracking task and its survival steps through the bridge, robot-agnostic (SPEC
"Legged robots", issues 25 §3 and 30): held-out expert references, each tracked from its first
state by the MPC service (``koopbridge serve mpc``, which picks the controller by the model's
kind) with the robot's adapter in lockstep in a child process; beside each model the open-loop
replay floor (the expert's recorded targets replayed from the same start). The robot is a
``LeggedRobot`` of ``ROBOTS`` (its adapter module, state layout, threshold, expert, names);
``go2_survival`` and ``g1_survival`` are the command lines. Writes ``report.json``,
``survival.png``, ``tracking.png``, ``tracking.mcap``, ``table.md`` and ``onpolicy/{model}.npz``
(see ``go2_survival``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Self

import numpy as np

from .. import BridgeTimeout, Client, RemoteError
from ..testing import listening_client
from .dataset_npz import DatasetMeta, save_dataset_npz, write_atomic
from .figure8 import koopbridge_cli
from .go2_track import GO2_LAYOUT, REFERENCE_SEED, Reference, Rollout, StateLayout, make_references, replay, rollout_windows, track

__all__ = ["G1", "GO2", "ROBOTS", "Bridge", "LeggedRobot", "ModelEntry", "SetupError", "main", "markdown_table", "model_entries",
           "parser", "q_weights", "references", "run", "stats"]

NAME = re.compile(r"^[a-z0-9_-]+$")


def _no_args(p: argparse.ArgumentParser) -> None:
    return None


def _none(a: argparse.Namespace) -> list[str]:
    return []


def _go2_sim(a: argparse.Namespace | None, memory: int) -> Any:
    from ..adapters.go2_sim import Go2Simulator

    return Go2Simulator(on_fall=None, memory=memory)


def _go2_policy(sim: Any) -> Any:
    from ..adapters.legged_collect import ExpertPolicy

    return ExpertPolicy(windows_per_episode=1, warmup=1.0, command_every=2.0)


def _go2_fall() -> Any:
    from ..adapters.go2_model import FALL

    return FALL


def _g1_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--held", choices=("servo", "locked"), default="locked", help="the adapter's --held: the 6 non-input joints "
                   "locked rigid, as on the 23-DoF G1 (default: %(default)s; replay floor 198.6 of 200 steps), or held by their servos "
                   "(the waist moves outside the state: replay floor 36.5)")
    p.add_argument("--expert", choices=("fastsac", "ppo"), default="fastsac", help="the walking policy of the references (default: %(default)s)")


def _g1_adapter_args(a: argparse.Namespace) -> list[str]:
    return ["--held", a.held, "--expert", a.expert]


def _g1_sim(a: argparse.Namespace | None, memory: int) -> Any:
    from ..adapters.g1_sim import G1Simulator

    held, expert = (a.held, a.expert) if a is not None else ("locked", "fastsac")
    return G1Simulator(policy_name=expert, held=held, memory=memory, on_fall=None)


def _g1_policy(sim: Any) -> Any:
    return sim.expert_policy({"kind": "expert", "windows_per_episode": 1, "warmup": 1.0, "command_every": 2.0})


def _g1_fall() -> Any:
    from ..adapters.g1_model import FALL

    return FALL


def _g1_task(a: argparse.Namespace) -> dict[str, Any]:
    return dict(held=a.held, expert=a.expert)


@dataclass(frozen=True)
class LeggedRobot:
    """What the survival task needs to know of a robot.

    ``name``: its short name (the simulator's id, model folder prefix); ``title``: its name in
    messages and figures; ``prog``: the command line's module (``koopbridge.experiments.{prog}``)
    and message prefix; ``adapter``: the adapter's module; ``nx``/``nu``: its state and input
    sizes; ``layout``: where the state keeps the joints, quaternion and base height;
    ``threshold``/``steps``: the default survival threshold (rad) and reference length;
    ``env``: the env name when the adapter reports none; ``simulator(args, memory)``: an
    in-process simulator like the adapter's (references); ``policy(sim)``: its expert's
    settings with one window per episode; ``fall()``: its ``FallRule``; ``held_out``/``start``:
    the report's sentences (``{seed}`` filled in); ``add_args``/``adapter_args``/``task``: its
    own command-line options, the adapter flags they give, the report fields they add.
    """

    name: str
    title: str
    prog: str
    adapter: str
    nx: int
    nu: int
    layout: StateLayout
    threshold: float
    steps: int
    env: str
    session_prefix: str
    simulator: Callable[[argparse.Namespace | None, int], Any]
    policy: Callable[[Any], Any]
    fall: Callable[[], Any]
    held_out: str
    start: str
    example: str
    add_args: Callable[[argparse.ArgumentParser], None] = _no_args
    adapter_args: Callable[[argparse.Namespace], list[str]] = _none
    task: Callable[[argparse.Namespace], dict[str, Any]] = field(default=lambda a: {})

    @property
    def sim_id(self) -> str:
        """The simulator's id on the bridge."""
        return self.name

    @property
    def mpc_id(self) -> str:
        """The MPC service's id on the bridge."""
        return f"{self.name}mpc"


#: The Unitree Go2 (issue 25).
GO2 = LeggedRobot(
    name="go2", title="Go2", prog="go2_survival", adapter="koopbridge.adapters.go2", nx=35, nu=12, layout=GO2_LAYOUT,
    threshold=0.16, steps=300, env="unitree-go2", session_prefix="g2", simulator=_go2_sim, policy=_go2_policy, fall=_go2_fall,
    held_out="expert rollouts (collect 'expert', one episode per reference, 1 s warm-up, command U([-0.5,-0.3,-0.8],[1,0.3,0.8]) "
    "every 2 s) drawn from default_rng([{seed}, i, 1]); the expert data draw from default_rng([data seed (42), e, 1])",
    start="reset(x0 = reference's first 35-D state) on an adapter that never saw it: lagged torques zero, base at x = y = 0",
    example="python -m koopbridge.experiments.go2_survival --model models/go2-both --model models/go2-edmd "
    "--model models/go2-nndm --references 50 --out results/go2-survival")

#: The Unitree G1 humanoid (issue 30): 53-D state (21 joints from column 10, pelvis height last),
#: 23 inputs, survival at 0.10 rad; the 23-DoF hardware (``--held locked``) by default.
G1 = LeggedRobot(
    name="g1", title="G1", prog="g1_survival", adapter="koopbridge.adapters.g1", nx=53, nu=23,
    layout=StateLayout(q=slice(10, 31), quat=slice(0, 4), height=52), threshold=0.10, steps=200, env="unitree-g1-locked",
    session_prefix="g1", simulator=_g1_sim, policy=_g1_policy, fall=_g1_fall,
    held_out="expert rollouts (holosoma's walking policy, collect 'expert', one episode per reference, 1 s warm-up, command "
    "U([-1,-1,-1],[1,1,1]) every 2 s) drawn from default_rng([{seed}, i, 1]); the expert data draw from default_rng([data seed (42), e, 1])",
    start="reset(x0 = reference's first 53-D state) on an adapter that never saw it: base at x = y = 0, wrist rolls at the default pose, "
    "solver cold",
    example="python -m koopbridge.experiments.g1_survival --model models/g1-both --model models/g1-edmd --references 50 --out results/g1-survival",
    add_args=_g1_args, adapter_args=_g1_adapter_args, task=_g1_task)

#: The robots by name.
ROBOTS: dict[str, LeggedRobot] = {r.name: r for r in (GO2, G1)}


def references(robot: LeggedRobot, n: int, steps: int, seed: int = REFERENCE_SEED, a: argparse.Namespace | None = None,
               skipped: list[dict[str, Any]] | None = None) -> list[Reference]:
    """``n`` held-out expert references of ``robot`` (``go2_track.make_references`` on in-process
    simulators built as the adapter is from the command line ``a``)."""
    sim = robot.simulator(a, 4096)
    return make_references(n, steps, seed, sim=sim, probe=robot.simulator(a, 0), policy=robot.policy(sim), skipped=skipped)


def references_from_file(path: str, steps: int) -> list[Reference]:
    """The references of a tracking task's file (``legged_references``: ``x`` (N, T+1, nx), ``u``
    (N, T, nu)), cut to ``steps`` transitions; ``SetupError`` when it cannot serve."""
    try:
        with np.load(path) as z:
            x, u = np.asarray(z["x"], float), np.asarray(z["u"], float)
    except (OSError, KeyError, ValueError) as e:
        raise SetupError(f"--references-file {path}: {e}") from e
    if x.ndim != 3 or u.shape[:2] != (x.shape[0], x.shape[1] - 1) or x.shape[1] - 1 < steps:
        raise SetupError(f"--references-file {path}: x {x.shape} and u {u.shape} do not hold {steps}-step references")
    return [Reference(x=x[i, : steps + 1].copy(), u=u[i, :steps].copy(), index=i, seed=-1) for i in range(len(x))]


class SetupError(Exception):
    """Bad input found before or while setting up (a missing model, a wrong nx): exit code 2."""


class ModelEntry:
    """One ``--model``: its folder, the name it is served under, its kind and config."""

    def __init__(self, path: Path, label: str, config: dict[str, Any]):
        self.path, self.label, self.config = path, label, config
        self.kind = str(config.get("kind", "?"))


def model_entries(dirs: Sequence[str]) -> list[ModelEntry]:
    """The models of ``dirs`` with unique store names (the folder's name when it is a valid
    ``[a-z0-9_-]`` name, else ``m{i}``); ``SetupError`` naming a folder that is missing or is
    no model folder."""
    out: list[ModelEntry] = []
    for i, d in enumerate(dirs):
        p = Path(d).resolve()
        cfg_path = p / "config.json"
        if not p.is_dir():
            raise SetupError(f"model folder {d} does not exist")
        if not cfg_path.is_file():
            raise SetupError(f"{d} is not a model folder (no config.json)")
        try:
            cfg = json.loads(cfg_path.read_text())
        except (OSError, ValueError) as e:
            raise SetupError(f"{cfg_path}: {e}") from e
        label = p.name if NAME.match(p.name) else f"m{i}"
        if any(e.label == label for e in out):
            label = f"{label}-{i}"
        out.append(ModelEntry(p, label, cfg))
    if not out:
        raise SetupError("no --model given")
    return out


def stats(v: Sequence[float], cap: int | None = None) -> dict[str, Any]:
    """Mean, spread (sample std, standard error, quartiles, range) and count of ``v``."""
    a = np.asarray(v, float)
    if a.size == 0:
        return dict(n=0)
    sd = float(a.std(ddof=1)) if a.size > 1 else 0.0
    d = dict(n=int(a.size), mean=round(float(a.mean()), 3), std=round(sd, 3), sem=round(sd / float(np.sqrt(a.size)), 3),
             median=float(np.median(a)), q25=float(np.percentile(a, 25)), q75=float(np.percentile(a, 75)),
             min=float(a.min()), max=float(a.max()))
    if cap is not None:
        d["at_cap"] = int(np.sum(a >= cap))
    return d


def _us(v: list[float]) -> dict[str, float] | None:
    if not v:
        return None
    a = np.asarray(v) * 1e6
    return dict(median_us=round(float(np.median(a)), 1), p99_us=round(float(np.percentile(a, 99)), 1), n=int(a.size))


class Bridge:
    """The robot's adapter (``python -m {robot.adapter}``) and the MPC service (``koopbridge
    serve mpc``, its store a temporary folder of links to the models) as child processes of
    one fresh session, and a ``Client`` of it; logs in ``log_dir``. A context manager."""

    def __init__(self, robot: LeggedRobot, models: list[ModelEntry], log_dir: Path, session: str | None = None,
                 adapter_args: Sequence[str] = ()):
        self.robot, self.models, self.log_dir = robot, models, log_dir
        self.session = session or robot.session_prefix + uuid.uuid4().hex[:10]
        self.adapter_args = list(adapter_args)
        self.procs: list[subprocess.Popen[bytes]] = []
        self.logs: list[Any] = []
        self.tmp = Path(tempfile.mkdtemp(prefix=f"{robot.name}-survival-"))
        self.client: Client | None = None
        self.info: dict[str, Any] = {}

    def __enter__(self) -> Self:
        store = self.tmp / "store"
        store.mkdir()
        for m in self.models:
            os.symlink(m.path, store / m.label)
        self.client, ep = listening_client(self.session)
        adapter = [sys.executable, "-m", self.robot.adapter, "--session", self.session, "--id", self.robot.sim_id, "--connect", ep, "--quiet",
                   *self.adapter_args]
        serve = [koopbridge_cli(), "serve", "mpc", "--session", self.session, "--id", self.robot.mpc_id, "--store", str(store),
                 "--state-dir", str(self.tmp / "state"), "--connect", ep]
        self.log_dir.mkdir(parents=True, exist_ok=True)
        try:
            for name, cmd in (("adapter", adapter), ("mpc-service", serve)):
                f = open(self.log_dir / f"{name}.log", "wb")
                self.logs.append(f)
                self.procs.append(subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.PIPE))
            self.info = self.client.connect_sim(self.robot.sim_id, timeout=120)
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def configure(self, m: ModelEntry, **mpc: Any) -> dict[str, Any]:
        """Loads model ``m`` into the MPC service with the MPC settings ``mpc`` (retrying until
        the service is up, 60 s); ``SetupError`` when the service refuses the model."""
        assert self.client is not None
        deadline = time.monotonic() + 60
        while True:
            try:
                return self.client.configure_mpc(self.robot.mpc_id, m.label, **mpc)
            except BridgeTimeout:
                if time.monotonic() > deadline or any(p.poll() is not None for p in self.procs):
                    raise
            except RemoteError as e:
                raise SetupError(f"the MPC service refused model {m.path} ({m.kind}): {e}") from e

    def __exit__(self, *exc: object) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None
        for p in self.procs:
            p.terminate()
        for p in self.procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        for f in self.logs:
            f.close()
        shutil.rmtree(self.tmp, ignore_errors=True)


def _fall_rule(robot: LeggedRobot, info: dict[str, Any]) -> Any:
    """``fallen(quat, height)`` from the adapter's info (``extra.mujoco.fall``), else the robot's."""
    from ..adapters.legged import FallRule

    f = (info.get("extra") or {}).get("mujoco", {}).get("fall")
    rule = FallRule(float(f["min_height_m"]), float(f["max_tilt_rad"])) if f else robot.fall()
    return rule.fallen


def q_weights(spec: str, models: list[ModelEntry], nx: int, refs: Sequence[Reference] = (), joints: slice | None = None) -> tuple[list[float] | None, str]:
    """The diagonal of Q and where it comes from: ``identity`` (None: Q = I on the raw state),
    ``zscore`` (Q = I on the z-scored state: 1/σ² with σ the first ``--normalise`` model's state
    statistics, else the references' own; the same Q for every model), ``joints`` (the z-scored
    weights on the ``joints`` slice, the joint positions survival scores, and 0 on every other
    state) or ``nx`` comma-separated weights."""
    if spec == "identity":
        return None, "identity (raw units)"
    if spec in ("zscore", "joints"):
        w, source = _zscore_weights(models, refs)
        if spec == "zscore":
            return w, f"zscore: {source}"
        if joints is None:
            raise SetupError("--q joints: this task names no joint positions")
        keep = np.zeros(nx, bool)
        keep[joints] = True
        return [v if keep[i] else 0.0 for i, v in enumerate(w)], f"joints: {source}, on states {joints.start}..{joints.stop - 1} only"
    try:
        w = [float(v) for v in spec.split(",")]
    except ValueError as e:
        raise SetupError(f"--q {spec!r}: expected identity, zscore, joints or {nx} comma-separated numbers") from e
    if len(w) != nx or not all(np.isfinite(w)) or min(w) < 0:
        raise SetupError(f"--q: {len(w)} weights given, expected {nx} finite numbers >= 0")
    return w, "given"


def _zscore_weights(models: list[ModelEntry], refs: Sequence[Reference]) -> tuple[list[float], str]:
    """1/σ² of the first normalised model's state statistics, else of the references' states."""
    for m in models:
        norm = m.config.get("normalisation")
        if norm:
            std = np.asarray(norm["x_std"], float)
            return (1.0 / np.maximum(std, 1e-8) ** 2).tolist(), f"1/std^2 of {m.label}'s normalisation (its train pool)"
    if refs:
        std = np.concatenate([r.x for r in refs]).std(axis=0)
        return (1.0 / np.maximum(std, 1e-8) ** 2).tolist(), "1/std^2 of the reference states (no normalised model given)"
    raise SetupError("--q zscore / joints needs a model trained with --normalise or references")


def run(robot: LeggedRobot, a: argparse.Namespace, refs: list[Reference] | None = None) -> dict[str, Any]:
    """Runs ``robot``'s task the parsed command line (``parser(robot)``) describes; returns the
    report (also written)."""
    out = Path(a.out)
    models = model_entries(a.model)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    for m in models:
        dims = (m.config.get("nx"), m.config.get("nu"))
        if None not in dims and dims != (robot.nx, robot.nu):
            raise SetupError(f"model {m.path} is {dims[0]}/{dims[1]}-D (nx/nu, its config.json); the {robot.title} is {robot.nx}/{robot.nu}-D")
    skipped: list[dict[str, Any]] = []
    if refs is None and a.references_file:
        refs = references_from_file(a.references_file, a.steps)
    refs = refs or references(robot, a.references, a.steps, a.seed, a, skipped)
    ref_s = time.perf_counter() - t0
    sim_id, mpc_id, lay, prog = robot.sim_id, robot.mpc_id, robot.layout, robot.prog
    with Bridge(robot, models, out / "logs", a.session, robot.adapter_args(a)) as br:
        assert br.client is not None
        c, info = br.client, br.info
        nx, nu = len(info["state_names"]), len(info["input_names"])
        if refs[0].x.shape[1] != nx or refs[0].u.shape[1] != nu:
            raise SetupError(f"the references are {refs[0].x.shape[1]}/{refs[0].u.shape[1]}-D, the adapter {nx}/{nu}-D")
        fallen = _fall_rule(robot, info)
        q, q_source = q_weights(a.q, models, nx, refs, lay.q)
        mpc_cfg = _mpc_settings(a.horizon, info, q, a.r)
        es_q, es_q_source = q_weights(a.error_state_q, models, nx, refs, lay.q)
        es_cfg = _mpc_settings(a.horizon, info, es_q, a.error_state_r)
        floor: list[Rollout] = [replay(c, sim_id, r, fallen, threshold=a.threshold, layout=lay) for r in refs]
        print(f"{prog}: replay floor {stats([f.survival for f in floor])}", file=sys.stderr, flush=True)
        results: dict[str, Any] = {}
        runs: dict[str, list[Rollout]] = {}
        for m in models:
            modes = [False] + ([True] if a.error_state and m.kind in ("koopman", "edmd") else [])
            for es in modes:
                conf = br.configure(m, **(es_cfg if es else mpc_cfg))
                if conf.get("nx") != nx or conf.get("nu") != nu:
                    raise SetupError(f"model {m.path} is {conf.get('nx')}/{conf.get('nu')}-D (nx/nu); the {robot.title} is {nx}/{nu}-D")
                label = f"{m.label}+error-state" if es else m.label
                t = time.perf_counter()
                rs = []
                for i, r in enumerate(refs):
                    rs.append(track(c, sim_id, mpc_id, m.label, r, fallen, horizon=a.horizon, threshold=a.threshold,
                                    stop_at_failure=not a.continue_after_failure, solve_timeout=a.solve_timeout, error_state=es, layout=lay))
                    if a.verbose:
                        print(f"{prog}: {label} reference {i}: survival {rs[-1].survival} (floor {floor[i].survival})", file=sys.stderr, flush=True)
                runs[label] = rs
                results[label] = _entry(m, conf, rs, floor, a.steps, time.perf_counter() - t, es)
                cfg = es_cfg if es else mpc_cfg
                results[label]["weights"] = dict(q=cfg.get("q"), r=cfg.get("r"))
                print(f"{prog}: {label} ({m.kind}) {results[label]['survival']}", file=sys.stderr, flush=True)
    error_state = dict(q=es_q_source, r=a.error_state_r) if a.error_state else None
    report = _report(robot, a, models, refs, floor, results, runs, info, q_source, ref_s, error_state)
    report["task"]["skipped_rollouts"] = skipped
    write_atomic(str(out / "report.json"), lambda f: f.write(json.dumps(report, indent=2).encode()))  # type: ignore[attr-defined]
    return report


def _mpc_settings(horizon: int, info: dict[str, Any], q: list[float] | None, r: float) -> dict[str, Any]:
    """The MPC service's settings: horizon, the adapter's input bounds, Q's diagonal (None: I)
    and R = r·I (none when r = 0)."""
    cfg: dict[str, Any] = dict(horizon=horizon, u_min=list(info["u_min"]), u_max=list(info["u_max"]))
    if q is not None:
        cfg["q"] = q
    if r > 0:
        cfg["r"] = [r] * len(info["u_min"])
    return cfg


def _entry(m: ModelEntry, conf: dict[str, Any], rs: list[Rollout], floor: list[Rollout], cap: int, wall: float, error_state: bool) -> dict[str, Any]:
    """The report entry of one model's runs over every reference."""
    surv = np.array([r.survival for r in rs])
    fl = np.array([f.survival for f in floor])
    statuses: dict[str, int] = {}
    for r in rs:
        for k, v in r.statuses.items():
            statuses[k] = statuses.get(k, 0) + v
    return dict(
        dir=str(m.path), kind=m.kind, normalised=bool(m.config.get("normalisation")), configure=conf,
        mpc="error-state about the reference, expert targets as feed-forward" if error_state else "SPEC (reference window)",
        survival=stats(surv.tolist(), cap), survivals=surv.tolist(), falls=int(sum(r.fell for r in rs)),
        above_floor=int(np.sum(surv > fl)), below_floor=int(np.sum(surv < fl)),
        solve=_us([s for r in rs for s in r.solve_s]), round_trip=_us([s for r in rs for s in r.round_trip_s]),
        statuses=statuses, sim_errors=[e for r in rs for e in r.errors][:10], wall_s=round(wall, 1))


def _report(robot: LeggedRobot, a: argparse.Namespace, models: list[ModelEntry], refs: list[Reference], floor: list[Rollout], results: dict[str, Any],
            runs: dict[str, list[Rollout]], info: dict[str, Any], q_source: str, ref_s: float,
            error_state: dict[str, Any] | None = None) -> dict[str, Any]:
    out = Path(a.out)
    fallen = _fall_rule(robot, info)
    floor_s = [f.survival for f in floor]
    table = [dict(controller="open-loop replay (floor)", **{k: v for k, v in stats(floor_s, a.steps).items()})]
    table += [dict(controller=f"{k} ({v['kind']})", **v["survival"]) for k, v in results.items()]
    onpolicy: dict[str, Any] = {}
    if not a.no_onpolicy:
        (out / "onpolicy").mkdir(exist_ok=True)
        for label, rs in runs.items():
            x, u = rollout_windows(rs, a.window_steps, fallen, robot.layout)
            rec: dict[str, Any] = dict(windows=int(len(x)))
            if len(x):
                path = out / "onpolicy" / f"{label}.npz"
                meta = DatasetMeta(env=str(info.get("env", robot.env)), dt=float(info["dt"]), state_names=list(info["state_names"]),
                                   input_names=list(info["input_names"]), seed=a.seed, source=f"koopbridge.experiments.{robot.prog} closed loops",
                                   policy=f"MPC ({label}, {results[label]['kind']}) tracking held-out expert references (seed {a.seed}); "
                                   f"windows of {a.window_steps} cut back to back from each run up to its end, failure or fall")
                save_dataset_npz(str(path), x, u, meta)
                rec["path"] = str(path)
            onpolicy[label] = rec
    shown = a.plot_reference if 0 <= a.plot_reference < len(refs) else 0
    figures: dict[str, str] = {}
    if not a.no_plot:
        from .go2_survival_plot import histogram, tracking

        histogram(str(out / "survival.png"), {"replay floor": floor_s, **{k: v["survivals"] for k, v in results.items()}}, a.steps, a.threshold)
        joints = [n.removesuffix("_q") for n in info["state_names"][robot.layout.q]]
        tracking(str(out / "tracking.png"), refs[shown].x, {"replay floor": floor[shown].x, **{k: runs[k][shown].x for k in runs}},
                 {"replay floor": floor[shown].survival, **{k: runs[k][shown].survival for k in runs}}, float(info["dt"]), joints,
                 q0=robot.layout.q.start, robot=robot.title)
        figures.update(histogram="survival.png", tracking="tracking.png")
    if not a.no_mcap and runs:
        from .go2_mcap import write_mcap

        first = next(iter(runs))
        r = runs[first][shown]
        write_mcap(str(out / "tracking.mcap"), robot.sim_id, str(info.get("env")), float(info["dt"]), list(info["state_names"]),
                   list(info["input_names"]), r.x, r.u, refs[shown].x)
        figures["mcap"] = f"tracking.mcap ({first}, reference {shown})"
    report = dict(
        task=dict(
            references=len(refs), reference_rollouts=[r.index for r in refs], steps=a.steps, dt=float(info["dt"]), reference_seed=a.seed,
            held_out=robot.held_out.format(seed=a.seed),
            start=robot.start,
            metric=f"survival = steps until mean_j |q_j - q_ref_j| > {a.threshold} rad or a fall (base < min height or tilted), capped at {a.steps}",
            horizon=a.horizon, q=q_source, r=a.r, error_state=error_state,
            bounds="the joint limits (the adapter's u_min/u_max)", stop_at_failure=not a.continue_after_failure, references_s=round(ref_s, 1),
            **robot.task(a)),
        table=table,
        floor=dict(survival=stats(floor_s, a.steps), survivals=floor_s, falls=int(sum(f.fell for f in floor)),
                   sim_errors=[e for f in floor for e in f.errors][:10]),
        models=results,
        onpolicy=onpolicy or None,
        figures=figures,
        plot_reference=shown,
    )
    write_atomic(str(out / "report.json"), lambda f: f.write(json.dumps(report, indent=2).encode()))  # type: ignore[attr-defined]
    write_atomic(str(out / "table.md"), lambda f: f.write(markdown_table(report).encode()))  # type: ignore[attr-defined]
    return report


def markdown_table(report: dict[str, Any]) -> str:
    """The survival table of ``report`` as Markdown (one row per controller, the floor first)."""
    t = report["task"]
    lines = [f"Survival steps over {t['references']} held-out references of {t['steps']} steps ({t['metric']}; Q {t['q']}, "
             f"H {t['horizon']}, R = {t['r']}" + (f"; error-state rows: Q {es['q']}, R = {es['r']}" if (es := t.get("error_state")) else "")
             + ")", "",
             "| controller | mean | std | sem | median | q25-q75 | min-max | at cap | above / below floor | solve median (p99) us |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    models = report["models"]
    for r in report["table"]:
        m = models.get(r["controller"].split(" ")[0])
        solve = m.get("solve") if m else None
        floor = f"{m['above_floor']} / {m['below_floor']}" if m else "-"
        timing = f"{solve['median_us']} ({solve['p99_us']})" if solve else "-"
        lines.append(f"| {r['controller']} | {r['mean']} | {r['std']} | {r['sem']} | {r['median']:g} | {r['q25']:g}-{r['q75']:g} | "
                     f"{r['min']:g}-{r['max']:g} | {r.get('at_cap', '')} | {floor} | {timing} |")
    return "\n".join(lines) + "\n"


def parser(robot: LeggedRobot, description: str) -> argparse.ArgumentParser:
    """The command line of ``python -m koopbridge.experiments.{robot.prog}``."""
    p = argparse.ArgumentParser(prog=f"python -m koopbridge.experiments.{robot.prog}", description=description,
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog="Example:\n  " + robot.example)
    p.add_argument("--model", action="append", required=True, metavar="DIR", help="a trained model folder (repeat for a table side by side)")
    p.add_argument("--references", type=int, default=50, help="held-out references (default: %(default)s)")
    p.add_argument("--steps", type=int, default=robot.steps, help="reference length L in steps of 0.02 s, the survival cap (default: %(default)s)")
    p.add_argument("--seed", type=int, default=REFERENCE_SEED, help="seed of the references (default: %(default)s; the expert data use 42)")
    p.add_argument("--references-file", metavar="NPZ", help="track the references of this file (legged_references' output, the "
                   "scenario engine's `references`) instead of making --references of them")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--horizon", type=int, default=15, help="MPC horizon H (default: %(default)s)")
    p.add_argument("--threshold", type=float, default=robot.threshold, help="mean joint-position error ending survival, rad "
                   f"(default: %(default)s, {robot.title})")
    p.add_argument("--q", default="zscore", help="diagonal of Q: zscore (Q = I on the z-scored state the Koopman models are trained on: "
                   "1/std^2 of the first normalised model's statistics, else of the references), identity (Q = I on the raw state, "
                   "dominated by the joint velocities) or nx comma-separated weights (default: %(default)s)")
    p.add_argument("--r", type=float, default=0.0, help="R = r I (default: %(default)s, SPEC)")
    p.add_argument("--error-state", action="store_true", help="also run, for each Koopman/EDMD model, the error-state MPC about the "
                   "reference (its state as the plan, the expert's targets as feed-forward, R on the deviation from them): the "
                   "recommended legged controller with --error-state-q/--error-state-r, a row beside SPEC's")
    p.add_argument("--error-state-q", default="joints", help="Q of the error-state rows, as --q, or joints: the z-scored weights on "
                   "the joint positions survival scores and 0 on every other state (default: %(default)s; docs/decisions/0017)")
    p.add_argument("--error-state-r", type=float, default=1.0, help="R = r I on u - u_ff in the error-state rows (default: %(default)s)")
    p.add_argument("--continue-after-failure", action="store_true", help="run each reference to its end (or a fall) after the error "
                   "threshold is crossed: more on-policy data (survival is the same)")
    p.add_argument("--window-steps", type=int, default=15, help="transitions per on-policy window (default: %(default)s, the data's T)")
    p.add_argument("--plot-reference", type=int, default=0, help="the reference drawn in tracking.png and recorded (default: %(default)s)")
    p.add_argument("--solve-timeout", type=float, default=60.0, help="seconds one solve may take (default: %(default)s)")
    p.add_argument("--no-plot", action="store_true", help="skip the PNG figures")
    p.add_argument("--no-mcap", action="store_true", help="skip tracking.mcap")
    p.add_argument("--no-onpolicy", action="store_true", help="skip onpolicy/*.npz")
    p.add_argument("--session", help="koopbridge session id (default: a fresh one)")
    p.add_argument("--verbose", action="store_true", help="a line per reference")
    robot.add_args(p)
    return p


def main(robot: LeggedRobot, argv: Sequence[str] | None = None, description: str = "") -> int:
    """Runs ``robot``'s task; returns the exit code (2: bad arguments, a missing or wrong model)."""
    a = parser(robot, description).parse_args(argv)
    if a.references < 1 or a.steps < 1 or a.horizon < 1 or a.window_steps < 1 or not a.threshold > 0:
        print(f"{robot.prog}: --references, --steps, --horizon, --window-steps must be >= 1 and --threshold > 0", file=sys.stderr)
        return 2
    if not (np.isfinite(a.r) and a.r >= 0 and np.isfinite(a.error_state_r) and a.error_state_r >= 0):
        print(f"{robot.prog}: --r and --error-state-r must be finite numbers >= 0", file=sys.stderr)
        return 2
    try:
        model_entries(a.model)
        report = run(robot, a)
    except (SetupError, FileNotFoundError) as e:
        print(f"{robot.prog}: {e}", file=sys.stderr)
        return 2
    print(json.dumps({r["controller"]: r.get("mean") for r in report["table"]}))
    return 0
