"""Windows per second of in-process collection on the MuJoCo Panda (``FrankaSimulator.collect``,
SPEC data: T = 15, U(±0.12)) against a bare ``mj_step`` loop over the same starts and commands,
measured alternately in one run; optionally the lockstep path over Zenoh for a few windows, and
N processes collecting at once.

    .venv/bin/python adapters/python/bench/bench_mujoco_collect.py --windows 2000 --repeats 3
    .venv/bin/python adapters/python/bench/bench_mujoco_collect.py --windows 2000 --procs 2
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import time

import mujoco
import numpy as np

from koopbridge.adapters.mujoco.sim import FrankaSimulator
from koopbridge.collect import UniformPolicy

POLICY = UniformPolicy(low=(-0.12,) * 7, high=(0.12,) * 7)


def bare(sim: FrankaSimulator, q0: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The same windows with nothing but MuJoCo calls: reset, set q, mj_forward, then per step
    ctrl, mj_step(nstep = substeps), and a copy of qpos/qvel."""
    m, d, n = sim.model, sim.data, sim.options.substeps
    lim = sim.options.u_limit
    out = np.empty((u.shape[0], u.shape[1] + 1, 14))
    for i in range(u.shape[0]):
        mujoco.mj_resetData(m, d)
        d.qpos[:7] = q0[i]
        mujoco.mj_forward(m, d)
        out[i, 0, :7], out[i, 0, 7:] = d.qpos[:7], d.qvel[:7]
        for t in range(u.shape[1]):
            d.ctrl[:] = np.clip(u[i, t], -lim, lim)
            mujoco.mj_step(m, d, nstep=n)
            out[i, t + 1, :7], out[i, t + 1, 7:] = d.qpos[:7], d.qvel[:7]
    return out


def one_process(n: int, T: int, start: int, barrier, out) -> None:
    """Builds a simulator, waits for the others, collects ``n`` windows (block ``start``) and
    reports its (start, end) wall-clock times."""
    sim = FrankaSimulator()
    barrier.wait()
    t0 = time.time()
    sim.collect(POLICY, 42, n, T, start=start)
    out.put((t0, time.time()))


def processes(k: int, n: int, T: int) -> float:
    """Windows per second of ``k`` processes collecting ``n`` windows each at the same time,
    from the first start to the last end (process start-up and model building excluded)."""
    ctx = mp.get_context("spawn")
    barrier, out = ctx.Barrier(k), ctx.Queue()
    ps = [ctx.Process(target=one_process, args=(n, T, i * n, barrier, out)) for i in range(k)]
    for p in ps:
        p.start()
    spans = [out.get() for _ in ps]
    for p in ps:
        p.join()
    return k * n / (max(e for _, e in spans) - min(s for s, _ in spans))


def lockstep(n: int, T: int) -> float:
    """Windows per second through SimulatorAdapter + Zenoh + the Rust client, one query per step."""
    import threading
    import uuid

    import koopbridge
    from koopbridge.testing import _free_endpoint

    sim = FrankaSimulator()
    w = sim.collect(POLICY, 42, n, T)
    ad = koopbridge.SimulatorAdapter(FrankaSimulator())
    session, ep = "bench" + uuid.uuid4().hex[:8], _free_endpoint()
    th = threading.Thread(target=ad.serve, kwargs=dict(session=session, id="arm", listen=[ep]), daemon=True)
    th.start()
    with koopbridge.Client(session=session, connect=[ep]) as c:
        c.connect_sim("arm", timeout=20)
        t0 = time.perf_counter()
        for i in range(n):
            c.reset("arm", seed=int(w.reset_seeds[i]))
            for t in range(T):
                c.step("arm", w.u[i, t])
        dt = time.perf_counter() - t0
    ad.stop()
    th.join()
    return n / dt


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--windows", type=int, default=2000)
    p.add_argument("--T", type=int, default=15)
    p.add_argument("--repeats", type=int, default=3, help="alternating collect/bare rounds")
    p.add_argument("--lockstep", type=int, default=200, help="windows through Zenoh (0: skip)")
    p.add_argument("--procs", type=int, default=0, help="also run this many processes at once")
    a = p.parse_args()
    sim = FrankaSimulator()
    res: dict[str, list[float] | float] = {"collect": [], "bare": []}
    for _ in range(a.repeats):
        t0 = time.perf_counter()
        w = sim.collect(POLICY, 42, a.windows, a.T)
        res["collect"].append(a.windows / (time.perf_counter() - t0))  # type: ignore[union-attr]
        t0 = time.perf_counter()
        out = bare(sim, w.x[:, 0, 3:10], w.u)
        res["bare"].append(a.windows / (time.perf_counter() - t0))  # type: ignore[union-attr]
        assert np.array_equal(out, w.x[:, :, 3:]), "the bare loop must compute the same windows"
    c, b = float(np.median(res["collect"])), float(np.median(res["bare"]))
    res["ratio_bare_over_collect"] = b / c
    res["spec_dataset_minutes_collect"] = 180_000 / c / 60
    if a.lockstep:
        res["lockstep_zenoh"] = lockstep(a.lockstep, a.T)
    if a.procs:
        res["procs_1"] = processes(1, a.windows, a.T)
        res[f"procs_{a.procs}"] = processes(a.procs, a.windows, a.T)
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
