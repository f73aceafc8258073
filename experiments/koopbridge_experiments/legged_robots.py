"""The legged robots of the paper's experiments (SPEC "Legged robots", issues 25 and 30): each robot's in-process simulator and expert
settings, and their held-out expert references (the tracking tasks themselves run in the scenario engine, ``koopbridge run``)."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "G1",
    "GO2",
    "GO2_LAYOUT",
    "REFERENCE_SEED",
    "ROBOTS",
    "LeggedRobot",
    "Reference",
    "SetupError",
    "StateLayout",
    "make_references",
    "references",
    "stats",
]

#: Seed of the reference rollouts. The expert data (``go2_data``) use seed 42, so its episodes
#: draw from ``default_rng([42, e, 1])``; reference i draws its reset and every velocity command
#: from ``default_rng([REFERENCE_SEED, i, 1])``, a stream no training episode uses: the
#: commands are continuous draws the data never saw.
REFERENCE_SEED = 90_042


@dataclass(frozen=True)
class StateLayout:
    """Where a legged robot's state keeps what survival scores: the joint positions ``q`` (a
    slice), the base quaternion ``quat`` (a slice) and the base height (an index)."""

    q: slice
    quat: slice
    height: int


#: The Go2's 35-D state: joint positions (12, from column 10), the quaternion, the base height last.
GO2_LAYOUT = StateLayout(q=slice(10, 22), quat=slice(0, 4), height=34)


@dataclass(frozen=True)
class Reference:
    """One held-out expert rollout: states ``x`` ``(L+1, nx)``, the expert's applied joint
    targets ``u`` ``(L, nu)`` (``u[k]`` drives ``x[k]`` to ``x[k+1]``), its index and seed."""

    x: np.ndarray
    u: np.ndarray
    index: int
    seed: int

    @property
    def steps(self) -> int:
        """The reference length L (transitions)."""
        return len(self.u)


class SetupError(Exception):
    """Bad input found before or while setting up (a missing model, a wrong nx): exit code 2."""


def make_references(n: int, steps: int, seed: int = REFERENCE_SEED, *, warmup: float = 1.0, command_every: float = 2.0,
                    sim: Any = None, skipped: list[dict[str, Any]] | None = None, probe: Any = None, policy: Any = None) -> list[Reference]:
    """``n`` held-out expert references of ``steps`` transitions, in-process on a fresh
    ``Go2Simulator`` (the adapter's defaults): rollout i is the expert collection's window i
    with one window per episode (``windows_per_episode`` 1, T = ``steps``), under ``seed``: a
    seeded reset, ``warmup`` s of walking unrecorded, then ``steps`` recorded steps under a
    random velocity command changed every ``command_every`` s. The references are the first
    ``n`` rollouts whose first state a fresh simulator accepts as ``reset(x0)`` (it refuses a
    base or leg too deep in the floor; until the adapter's 06:13 change of 4 Dec 2026 that
    refused 2 of the first 50 expert starts); the refused ones are appended to ``skipped``.
    Another robot: ``sim`` (collecting), ``probe`` (a memoryless simulator judging the starts)
    and ``policy`` (its expert's settings with one window per episode) given."""
    from koopbridge import InvalidInput
    from koopbridge.adapters.legged.collect import ExpertPolicy
    from koopbridge.adapters.legged.go2.sim import Go2Simulator

    if n < 1 or steps < 1:
        raise ValueError(f"references: need n >= 1 and steps >= 1, got {n}, {steps}")
    sim = sim or Go2Simulator(on_fall=None)
    probe = probe or Go2Simulator(on_fall=None, memory=0)
    policy = policy or ExpertPolicy(windows_per_episode=1, warmup=warmup, command_every=command_every)
    out: list[Reference] = []
    start = 0
    while len(out) < n:
        if start > 2 * n + 20:
            raise ValueError(f"references: {start - len(out)} of {start} expert rollouts start in states the simulator refuses")
        w = sim.collect(policy, seed, n - len(out), steps, start=start)
        for j in range(len(w.x)):
            try:
                probe.reset(x0=w.x[j, 0])
            except InvalidInput as e:
                if skipped is not None:
                    skipped.append(dict(index=start + j, reason=str(e)))
                continue
            out.append(Reference(x=w.x[j].copy(), u=w.u[j].copy(), index=start + j, seed=seed))
        start += len(w.x)
    return out


def _go2_sim(a: argparse.Namespace | None, memory: int) -> Any:
    from koopbridge.adapters.legged.go2.sim import Go2Simulator

    return Go2Simulator(on_fall=None, memory=memory)


def _go2_policy(sim: Any) -> Any:
    from koopbridge.adapters.legged.collect import ExpertPolicy

    return ExpertPolicy(windows_per_episode=1, warmup=1.0, command_every=2.0)


def _go2_fall() -> Any:
    from koopbridge.adapters.legged.go2.model import FALL

    return FALL


def _g1_sim(a: argparse.Namespace | None, memory: int) -> Any:
    from koopbridge.adapters.legged.g1.sim import G1Simulator

    held, expert = (a.held, a.expert) if a is not None else ("locked", "fastsac")
    return G1Simulator(policy_name=expert, held=held, memory=memory, on_fall=None)


def _g1_policy(sim: Any) -> Any:
    return sim.expert_policy({"kind": "expert", "windows_per_episode": 1, "warmup": 1.0, "command_every": 2.0})


def _g1_fall() -> Any:
    from koopbridge.adapters.legged.g1.model import FALL

    return FALL


@dataclass(frozen=True)
class LeggedRobot:
    """What the experiments need to know of a robot.

    ``name``: its short name (the simulator's id, the ``--robot`` choice); ``title``: its name
    in messages; ``nx``/``nu``: its state and input sizes; ``layout``: where the state keeps
    the joints, quaternion and base height; ``steps``: the default reference length (the
    survival cap); ``env``: the env name when the simulator reports none;
    ``simulator(args, memory)``: an in-process simulator like the adapter's (``args``: the
    command line's ``--held``/``--expert``, None for the defaults); ``policy(sim)``: its
    expert's settings with one window per episode; ``fall()``: its ``FallRule``;
    ``held_out``: the references' description (``{seed}`` filled in).
    """

    name: str
    title: str
    nx: int
    nu: int
    layout: StateLayout
    steps: int
    env: str
    simulator: Callable[[argparse.Namespace | None, int], Any]
    policy: Callable[[Any], Any]
    fall: Callable[[], Any]
    held_out: str


#: The Unitree Go2 (issue 25).
GO2 = LeggedRobot(
    name="go2", title="Go2", nx=35, nu=12, layout=GO2_LAYOUT, steps=300, env="unitree-go2", simulator=_go2_sim, policy=_go2_policy,
    fall=_go2_fall,
    held_out="expert rollouts (collect 'expert', one episode per reference, 1 s warm-up, command U([-0.5,-0.3,-0.8],[1,0.3,0.8]) "
    "every 2 s) drawn from default_rng([{seed}, i, 1]); the expert data draw from default_rng([data seed (42), e, 1])")

#: The Unitree G1 humanoid (issue 30): 53-D state (21 joints from column 10, pelvis height last),
#: 23 inputs; the 23-DoF hardware (``--held locked``) by default.
G1 = LeggedRobot(
    name="g1", title="G1", nx=53, nu=23, layout=StateLayout(q=slice(10, 31), quat=slice(0, 4), height=52), steps=200,
    env="unitree-g1-locked", simulator=_g1_sim, policy=_g1_policy, fall=_g1_fall,
    held_out="expert rollouts (holosoma's walking policy, collect 'expert', one episode per reference, 1 s warm-up, command "
    "U([-1,-1,-1],[1,1,1]) every 2 s) drawn from default_rng([{seed}, i, 1]); "
    "the expert data draw from default_rng([data seed (42), e, 1])")

#: The robots by name.
ROBOTS: dict[str, LeggedRobot] = {r.name: r for r in (GO2, G1)}


def references(robot: LeggedRobot, n: int, steps: int, seed: int = REFERENCE_SEED, a: argparse.Namespace | None = None,
               skipped: list[dict[str, Any]] | None = None) -> list[Reference]:
    """``n`` held-out expert references of ``robot`` (``make_references`` on in-process
    simulators built as the adapter is from the command line ``a``)."""
    sim = robot.simulator(a, 4096)
    return make_references(n, steps, seed, sim=sim, probe=robot.simulator(a, 0), policy=robot.policy(sim), skipped=skipped)


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
