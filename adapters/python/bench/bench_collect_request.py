"""The Zenoh ``collect`` request on the MuJoCo Panda against a bare ``mj_step`` loop, side by side
in one run, and K adapter processes against one.

Part 1 (``--windows``, SPEC: 180,000 windows of T = 15, commands U(±0.12)): an adapter process
(``python -m koopbridge.adapters.mujoco``) runs blocks of ``--block`` windows for the Rust
client (``Client.collect``); this process then runs the same windows (the starts and commands
the reply holds) with nothing but MuJoCo calls and checks that it computed the same states, bit
for bit. The two alternate every ``--round`` blocks, so that a change of machine load hits both.
Part 2 (``--procs K``, ``--proc-windows`` each): the same collection asked of one adapter
process, then of K processes at once (block j to process j mod K), windows/s of each.

    .venv/bin/python adapters/python/bench/bench_collect_request.py --windows 180000 --procs 2
    .venv/bin/python adapters/python/bench/bench_collect_request.py --windows 4000 --procs 2 --proc-windows 4000
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
import uuid

import numpy as np

import koopbridge
from koopbridge.adapters.mujoco.sim import FrankaSimulator
from koopbridge.testing import _free_endpoint

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_mujoco_collect import bare  # noqa: E402

POLICY = {"kind": "uniform", "low": -0.12, "high": 0.12}
SEED = 42


class Adapters:
    """K MuJoCo adapter processes, each listening on its own port, and one client of them."""

    def __init__(self, k: int, log_dir: str) -> None:
        self.session = "bench" + uuid.uuid4().hex[:8]
        self.eps = [_free_endpoint() for _ in range(k)]
        self.ids = [f"arm{j}" for j in range(k)]
        self.procs = []
        for sim_id, ep in zip(self.ids, self.eps, strict=True):
            log = open(os.path.join(log_dir, f"{sim_id}.log"), "wb")
            cmd = [sys.executable, "-m", "koopbridge.adapters.mujoco", "--session", self.session, "--id", sim_id, "--listen", ep]
            self.procs.append((subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.PIPE), log))
        self.client = koopbridge.Client(session=self.session, connect=self.eps)
        for sim_id in self.ids:
            self.client.connect_sim(sim_id, timeout=120)

    def block(self, j: int, b: int, block: int, T: int) -> tuple[np.ndarray, np.ndarray]:
        return self.client.collect(self.ids[j], seed=SEED, block=b, block_windows=block, steps=T, policy=POLICY)

    def close(self) -> None:
        self.client.close()
        for p, log in self.procs:
            p.kill()
            p.wait(timeout=10)
            log.close()


def side_by_side(ad: Adapters, sim: FrankaSimulator, windows: int, block: int, T: int, per_round: int) -> dict[str, float]:
    """Windows per second through the request and bare, alternating every ``per_round`` blocks;
    every block's states are recomputed by the bare loop and must be equal."""
    blocks = windows // block
    t_req = t_bare = 0.0
    done = 0
    for r0 in range(0, blocks, per_round):
        got = []
        t0 = time.perf_counter()
        for b in range(r0, min(r0 + per_round, blocks)):
            got.append(ad.block(0, b, block, T))
        t_req += time.perf_counter() - t0
        t0 = time.perf_counter()
        outs = [bare(sim, x[:, 0, 3:10], u) for x, u in got]
        t_bare += time.perf_counter() - t0
        for (x, _), out in zip(got, outs, strict=True):
            assert np.array_equal(out, x[:, :, 3:]), "the bare loop must compute the windows the adapter sent"
        done += sum(x.shape[0] for x, _ in got)
        print(f"  {done}/{blocks * block} windows: request {done / t_req:.1f}/s, bare {done / t_bare:.1f}/s", file=sys.stderr, flush=True)
    return {"windows": done, "request_per_s": done / t_req, "bare_per_s": done / t_bare, "ratio_request_over_bare_time": t_req / t_bare, "request_s": t_req, "bare_s": t_bare}


def spread(ad: Adapters, k: int, windows: int, block: int, T: int) -> float:
    """Windows per second of the first ``k`` adapters collecting ``windows`` windows together,
    block j to adapter j mod k, one client thread per adapter."""
    blocks = windows // block
    errors: list[BaseException] = []

    def run(j: int) -> None:
        try:
            for b in range(j, blocks, k):
                ad.block(j, b, block, T)
        except BaseException as e:  # reported below
            errors.append(e)

    ths = [threading.Thread(target=run, args=(j,)) for j in range(k)]
    t0 = time.perf_counter()
    for t in ths:
        t.start()
    for t in ths:
        t.join()
    if errors:
        raise errors[0]
    return blocks * block / (time.perf_counter() - t0)


def _print_log_tails(log_dir: str, ids: list[str], lines: int = 30) -> None:
    """The last ``lines`` lines of each adapter's log, on stderr (why an adapter went away)."""
    for sim_id in ids:
        path = os.path.join(log_dir, f"{sim_id}.log")
        with open(path, "rb") as f:
            tail = f.read().decode(errors="replace").splitlines()[-lines:]
        print(f"--- {path} (last {len(tail)} lines)", file=sys.stderr)
        print("\n".join(tail), file=sys.stderr, flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--windows", type=int, default=180_000, help="part 1: windows (SPEC: 180,000)")
    p.add_argument("--T", type=int, default=15)
    p.add_argument("--block", type=int, default=500)
    p.add_argument("--round", type=int, default=10, help="blocks per alternation")
    p.add_argument("--procs", type=int, default=2, help="part 2: adapter processes (0: skip)")
    p.add_argument("--proc-windows", type=int, default=20_000, help="part 2: windows per measurement")
    p.add_argument("--log-dir", help="keep the adapters' logs (ID.log) here (default: a temporary folder; "
                   "their last lines are printed if the bench fails)")
    a = p.parse_args()
    res: dict[str, object] = {"load_before": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory(prefix="bench-collect-") as tmp:
        logs = a.log_dir or tmp
        os.makedirs(logs, exist_ok=True)
        ad = Adapters(max(1, a.procs), logs)
        try:
            ad.block(0, 0, 2, a.T)  # warm-up (first MuJoCo step, Zenoh routes)
            if a.windows:
                res["side_by_side"] = side_by_side(ad, FrankaSimulator(), a.windows, a.block, a.T, a.round)
            if a.procs > 1:
                one = spread(ad, 1, a.proc_windows, a.block, a.T)
                many = spread(ad, a.procs, a.proc_windows, a.block, a.T)
                res["procs"] = {"1": one, str(a.procs): many, "speed-up": many / one}
        except BaseException:
            _print_log_tails(logs, ad.ids)
            raise
        finally:
            ad.close()
    res["load_after"] = os.getloadavg()[0]
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
