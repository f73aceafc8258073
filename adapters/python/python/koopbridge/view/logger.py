"""Turns a run's view messages (PROTOCOL.md §10: events, closed-loop states, trainer progress)
into Rerun entities, one plot per state group; knows nothing of Zenoh, so it is testable alone."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import rerun as rr

from .columns import Columns, Times
from .robots import GHOST_OFFSET, RobotPoser
from .video import VideoWriter

__all__ = ["RunLogger", "SimLayout", "loop_path", "path_chunk", "state_groups"]

# A group of at most this many states is one plot; more are split (a plot of 30 lines is unread).
MAX_GROUP = 12


def state_groups(names: Sequence[str], units: Sequence[str] | None = None) -> list[tuple[str, list[int]]]:
    """The plots of a simulator's states: by unit where the simulator names units (the Go2's
    joint angles in one plot, its velocities in another), else consecutive runs of at most
    ``MAX_GROUP``; each as (group name, state indices)."""
    groups: dict[str, list[int]] = {}
    if units is not None and len(units) == len(names):
        for i, u in enumerate(units):
            groups.setdefault(path_chunk(u if u != "1" else "unitless"), []).append(i)
    else:
        for i in range(len(names)):
            groups.setdefault(f"states_{i // MAX_GROUP}" if len(names) > MAX_GROUP else "states", []).append(i)
    out: list[tuple[str, list[int]]] = []
    for g, idx in groups.items():
        chunks = [idx[j : j + MAX_GROUP] for j in range(0, len(idx), MAX_GROUP)]
        out.extend((g if len(chunks) == 1 else f"{g}_{n}", c) for n, c in enumerate(chunks))
    return out


def path_chunk(text: str) -> str:
    """``text`` as one entity-path part (Rerun splits on ``/``)."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in text) or "_"


def loop_path(sim: str, what: str, row: str, episode: int | None) -> str:
    """The entity path of ``what`` (``state/{group}``, ``input``, ``solve_us``, ``plan/{group}``,
    ``events``) of one closed loop: ``control/{sim}/{what}/{row}`` and, in a tracking task, the
    reference's index (``…/ref007``); what a plot shows is then a path prefix."""
    base = f"control/{path_chunk(sim)}/{what}/{path_chunk(row)}"
    return base if episode is None else f"{base}/ref{episode:03d}"


@dataclass
class SimLayout:
    """What the viewer knows of a simulator from its ``info``: names, bounds and the plots."""

    state_names: list[str]
    input_names: list[str]
    u_min: list[float]
    u_max: list[float]
    groups: list[tuple[str, list[int]]] = field(default_factory=list)
    robot: RobotPoser | None = None
    dt: float = 0.0

    @staticmethod
    def from_info(info: dict[str, Any], robot: RobotPoser | None = None) -> SimLayout:
        names = list(info.get("state_names", []))
        return SimLayout(
            state_names=names,
            input_names=list(info.get("input_names", [])),
            u_min=[_num(v) for v in info.get("u_min", [])],
            u_max=[_num(v) for v in info.get("u_max", [])],
            groups=state_groups(names, state_units(info)),
            robot=robot,
            dt=_num(info.get("dt", 0.0)),
        )

    @staticmethod
    def unnamed(nx: int, nu: int) -> SimLayout:
        """A layout for a simulator whose ``info`` could not be read."""
        names = [f"x{i}" for i in range(nx)]
        return SimLayout(names, [f"u{i}" for i in range(nu)], [], [], state_groups(names))


def state_units(info: dict[str, Any]) -> list[str] | None:
    """The state's units where the simulator names them in its ``extra`` (``units.state`` of any
    section, e.g. ``extra.mujoco.units.state``)."""
    extra = info.get("extra")
    if not isinstance(extra, dict):
        return None
    for section in [extra, *[v for v in extra.values() if isinstance(v, dict)]]:
        units = section.get("units")
        if isinstance(units, dict) and isinstance(units.get("state"), list):
            return [str(u) for u in units["state"]]
    return None


def _num(v: Any) -> float:
    """A JSON number, ``null`` (a non-finite value) as NaN."""
    return float("nan") if v is None else float(v)


def _vec(v: Sequence[Any] | None) -> np.ndarray:
    return np.array([_num(a) for a in (v or [])], dtype=np.float64)


class RunLogger:
    """Logs the view messages of one run into a Rerun recording (``rec``). ``layout_of(sim, nx,
    nu)`` gives a simulator's :class:`SimLayout` (asked once per simulator); ``blueprint(layouts)``
    the viewer's layout for the simulators seen so far (sent again when one appears); ``video``
    renders the chosen references' loops of MuJoCo simulators into MP4s."""

    def __init__(
        self,
        rec: rr.RecordingStream,
        layout_of: Callable[[str, int, int], SimLayout],
        blueprint: Callable[[Mapping[str, SimLayout]], Any] | None = None,
        video: VideoWriter | None = None,
    ) -> None:
        self.rec = rec
        self.video = video
        self._blueprint = blueprint
        self._layout_of = layout_of
        self._layouts: dict[str, SimLayout] = {}
        self._declared: set[str] = set()
        self._ticks: dict[str, int] = {}
        self._jobs: dict[str, str] = {}
        self._robots_drawn: set[str] = set()
        self._columns = Columns(rec)
        self.steps_logged = 0

    # ---- closed loops ----

    def step(self, sim: str, m: dict[str, Any], wall_s: float) -> None:
        """One state of a closed loop (``…/view/{sim}/step``), received ``wall_s`` after the
        viewer started (the ``wall`` timeline every plot shares)."""
        x = _vec(m["x"])
        u = _vec(m.get("u")) if m.get("u") is not None else None
        lay = self._layouts.get(sim)
        if lay is None:
            lay = self._layouts[sim] = self._layout_of(sim, len(x), 0 if u is None else len(u))
            self.send_layout()
            self._declare_sim(sim, lay)
        row, episode = str(m.get("row", "")), m.get("episode")

        def at(what: str) -> str:
            return loop_path(sim, what, row, episode)

        self._declare(sim, row, episode, lay)
        tick = self._ticks.get(sim, 0)
        self._ticks[sim] = tick + 1
        k = int(m["k"])
        times = {("wall", "duration"): wall_s, ("step", "sequence"): k, (f"{path_chunk(sim)}_tick", "sequence"): tick}
        cols = self._columns
        ref = _vec(m.get("reference"))
        for g, idx in lay.groups:
            cols.scalars(f"{at(f'state/{g}')}/x", times, x[idx])
            if len(ref) == len(x):
                cols.scalars(f"{at(f'state/{g}')}/reference", times, ref[idx])
        if u is not None:
            cols.scalars(at("input"), times, u)
        if m.get("solve_us") is not None:
            cols.scalars(at("solve_us"), times, np.array([float(m["solve_us"])]))
            if m.get("status") not in (None, "solved"):
                self.rec.set_time("wall", duration=wall_s)
                self.rec.set_time("step", sequence=k)
                self.rec.log(at("events"), rr.TextLog(f"step {k}: MPC {m['status']}", level="WARN"))
        plan = m.get("plan")
        if plan:
            p = np.array([[_num(v) for v in r] for r in plan], dtype=np.float64)
            # Seconds ahead of this state: a fixed axis on the scale of the states (a 2D view keeps
            # its aspect ratio, so steps ahead would flatten every curve).
            ahead = np.arange(len(p), dtype=np.float64) * (lay.dt if lay.dt > 0 else 1.0)
            for g, idx in lay.groups:
                cols.strips(at(f"plan/{g}"), times, np.stack([np.column_stack([ahead, p[:, i]]) for i in idx]))
        if lay.robot is not None:
            self._robot(sim, lay.robot, x, ref if len(ref) == len(x) else None, times)
            if self.video is not None and self.video.wants(episode):
                self.video.add(lay.robot, sim, row, episode, k, lay.dt, x, ref if len(ref) == len(x) else None, last=u is None)
        self.steps_logged += 1

    def _robot(self, sim: str, robot: RobotPoser, x: np.ndarray, ref: np.ndarray | None, times: Times) -> None:
        """Queues the robot's pose (and its reference ghost's) for ``robot/{sim}``."""
        root = f"robot/{path_chunk(sim)}"
        if root not in self._robots_drawn:
            self._robots_drawn.add(root)
            robot.log_geometry(self.rec, f"{root}/actual")
            robot.log_geometry(self.rec, f"{root}/reference", ghost=True)
        for which, state, offset in (("actual", x, None), ("reference", ref, GHOST_OFFSET)):
            pose = None if state is None else robot.pose(state, offset)
            if pose is not None:
                self._columns.pose(f"{root}/{which}", times, robot, pose)

    def flush(self) -> None:
        """Sends the queued rows and robot poses (call when nothing else is waiting, and at the
        end)."""
        self._columns.flush()

    def _declare(self, sim: str, row: str, episode: int | None, lay: SimLayout) -> None:
        """The series names of one loop's entities, once (static)."""
        key = loop_path(sim, "", row, episode)
        if key in self._declared:
            return
        self._declared.add(key)
        for g, idx in lay.groups:
            names = [lay.state_names[i] for i in idx]
            base = loop_path(sim, f"state/{g}", row, episode)
            self.rec.log(f"{base}/x", rr.SeriesLines(names=names), static=True)
            self.rec.log(f"{base}/reference", rr.SeriesLines(names=[f"{n} (reference)" for n in names], widths=1.0), static=True)
        if lay.input_names:
            self.rec.log(loop_path(sim, "input", row, episode), rr.SeriesLines(names=lay.input_names), static=True)

    def _declare_sim(self, sim: str, lay: SimLayout) -> None:
        """A simulator's input bounds (static, once)."""
        bounds = [(n, lo, hi) for n, lo, hi in zip(lay.input_names, lay.u_min, lay.u_max, strict=False) if math.isfinite(lo) and math.isfinite(hi)]
        if bounds:
            text = ", ".join(f"{n} ∈ [{lo:g}, {hi:g}]" for n, lo, hi in bounds)
            self.rec.log(f"control/{path_chunk(sim)}/input_bounds", rr.TextDocument(text), static=True)

    def send_layout(self) -> None:
        """Sends the layout for the simulators seen so far (it replaces the previous one)."""
        if self._blueprint is not None:
            self.rec.send_blueprint(self._blueprint(self._layouts))

    # ---- the run's events and the trainer ----

    def event(self, m: dict[str, Any], wall_s: float) -> None:
        """A run event (``…/view/events``): a phase, a warning, collection or control progress."""
        rec = self.rec
        rec.reset_time()
        rec.set_time("wall", duration=wall_s)
        kind = m.get("event")
        if kind == "phase":
            rec.log("run/log", rr.TextLog(str(m.get("text", "")), level="INFO"))
        elif kind == "warning":
            rec.log("run/log", rr.TextLog(str(m.get("text", "")), level="WARN"))
        elif kind == "collect":
            rec.log(f"run/collect/{path_chunk(str(m.get('split', '')))}", rr.Scalars([float(m.get("done", 0))]))
        elif kind == "control":
            rec.log("run/control_progress", rr.Scalars([float(m.get("done", 0))]))

    def train_progress(self, job: str, m: dict[str, Any], wall_s: float, model: str | None = None) -> None:
        """One progress message of a trainer job (PROTOCOL.md §5), under ``train/{model or job}``,
        received ``wall_s`` after the viewer started."""
        name = path_chunk(model or job)
        rec = self.rec
        rec.reset_time()
        rec.set_time("wall", duration=wall_s)
        if "iteration" not in m:
            if m.get("state"):
                rec.log(f"train/{name}/log", rr.TextLog(f"job {job}: {m['state']} {m.get('error') or ''}".strip()))
            return
        rec.set_time("iteration", sequence=int(m["iteration"]))
        loss = m.get("loss") or {}
        for term in ("total", "pred", "ctrl", "cov"):
            if isinstance(loss.get(term), (int, float)):
                rec.log(f"train/{name}/loss/{term}", rr.Scalars([float(loss[term])]))
        if isinstance(m.get("validation"), (int, float)):
            rec.log(f"train/{name}/validation", rr.Scalars([float(m["validation"])]))
