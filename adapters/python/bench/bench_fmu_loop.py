"""Benchmarks of the Python side, all in one run on loopback (figures for BENCHMARKS.md):

1. round trip of a bare Zenoh query (Rust echo queryable, `koopbridge bench bridge --echo-server`);
2. lockstep step round trip of a Python adapter whose step does nothing (the SDK's own cost);
3. lockstep step round trip of the FMU adapter (damped pendulum FMU, fmpy);
4. lockstep step rate of the FMU pendulum with MPC in the loop: each macro step one MPC solve
   by the MPC service (`koopbridge serve mpc`, SPEC-size model N = 34, H = 15) and one FMU step.

Rounds of each measurement are interleaved so that they see the same machine load. All queries
go through koopbridge.Client (bridge's Rust client), so the Python call overhead is in every row.

Usage: .venv/bin/python adapters/python/bench/bench_fmu_loop.py [--iterations 2000] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np

import koopbridge

ROOT = Path(__file__).resolve().parents[3]


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def find_koopbridge() -> str:
    for c in (os.environ.get("KOOPBRIDGE_BIN"), os.path.join(os.environ.get("CARGO_TARGET_DIR", ""), "release", "koopbridge"), ROOT / "target/release/koopbridge"):
        if c and os.path.isfile(c):
            return str(c)
    sys.exit("error: the koopbridge CLI is not built (cargo build --release --bin koopbridge), or set KOOPBRIDGE_BIN")


def stats(us: list[float]) -> dict[str, float]:
    a = np.sort(np.asarray(us))
    return dict(median_us=float(np.median(a)), p99_us=float(a[min(len(a) - 1, int(0.99 * len(a)))]), n=len(a))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=2000, help="round trips per measurement (after warm-up)")
    ap.add_argument("--loop-steps", type=int, default=1000, help="macro steps of the MPC-in-the-loop measurement")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench-python"), help="scratch and result folder")
    args = ap.parse_args()
    out = Path(args.out)
    (out / "logs").mkdir(parents=True, exist_ok=True)
    exe = find_koopbridge()
    session = "bench" + uuid.uuid4().hex[:8]
    ep = free_endpoint()
    store = out / "models"
    koopbridge.KoopmanModel.init(nx=2, nu=1).save(str(store / "bench-pendulum"))  # SPEC architecture
    fmu = ROOT / "adapters/fmu/build/damped_pendulum.fmu"
    py = sys.executable
    cmds = {
        "echo": [exe, "bench", "bridge", "--echo-server", session, "--connect", ep],
        "null": [py, str(ROOT / "adapters/python/bench/null_adapter.py"), "--session", session, "--id", "null", "--connect", ep, "--stdin-lifeline"],
        "fmu": [py, "-m", "koopbridge.adapters.fmu", str(fmu), "--inputs", "u", "--outputs", "theta,omega", "--dt", "0.02",
                "--initial", "theta0,omega0", "--u-min=-8", "--u-max=8", "--session", session, "--id", "fmu", "--connect", ep, "--stdin-lifeline"],
        "mpc": [exe, "serve", "mpc", "--session", session, "--id", "m0", "--store", str(store), "--state-dir", str(out / "state"),
                "--connect", ep, "--stdin-lifeline"],
    }
    procs = []
    c = koopbridge.Client(session=session, listen=[ep])
    try:
        for name, cmd in cmds.items():
            log = open(out / "logs" / f"{name}.log", "wb")
            procs.append(subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=log, stderr=subprocess.STDOUT))
        c.connect_sim("null", timeout=60)
        c.connect_sim("fmu", timeout=60)
        t_end = time.monotonic() + 60
        while True:
            try:
                c.query("bench/echo", b"x", 1.0)
                break
            except koopbridge.KoopbridgeError:
                if time.monotonic() > t_end:
                    raise
        while True:
            try:
                cfg = json.loads(c.query("mpc/m0/configure", json.dumps({"model": "bench-pendulum", "mpc": {"horizon": 15, "u_min": [-8.0], "u_max": [8.0]}}).encode(), 5.0))
                break
            except koopbridge.KoopbridgeError:
                if time.monotonic() > t_end:
                    raise
                time.sleep(0.1)
        payload = b"KB\x01\x01" + bytes(8) + (1).to_bytes(4, "little") + bytes(8)  # a step request's size
        c.reset("null", x0=[0.0, 0.0])
        c.reset("fmu", x0=[0.1, 0.0])
        u = np.array([0.0])
        samples: dict[str, list[float]] = {"bare_zenoh_query": [], "python_adapter_step": [], "fmu_adapter_step": []}
        rounds, per = 10, max(1, args.iterations // 10)
        for _ in range(200):  # warm-up
            c.query("bench/echo", payload)
            c.step("null", u)
            c.step("fmu", u)
        for _ in range(rounds):
            for key, f in (("bare_zenoh_query", lambda: c.query("bench/echo", payload)), ("python_adapter_step", lambda: c.step("null", u)), ("fmu_adapter_step", lambda: c.step("fmu", u))):
                s = samples[key]
                for _ in range(per):
                    t0 = time.perf_counter()
                    f()
                    s.append((time.perf_counter() - t0) * 1e6)
        result = {k: stats(v) for k, v in samples.items()}
        bare = result["bare_zenoh_query"]["median_us"]
        for k in ("python_adapter_step", "fmu_adapter_step"):
            result[k]["ratio_to_bare"] = result[k]["median_us"] / bare
        # MPC in the loop: x -> solve (service) -> step (FMU), regulation from [-2.5, 0.1] to 0.
        x = c.reset("fmu", x0=[-2.5, 0.1])
        ref = np.zeros(2)
        solve_us, step_us = [], []
        t0 = time.perf_counter()
        for _ in range(args.loop_steps):
            a = time.perf_counter()
            sol = c.solve("m0", x, ref, model="bench-pendulum", nu=1)
            b = time.perf_counter()
            _, _, x = c.step("fmu", sol["u"][0])
            solve_us.append((b - a) * 1e6)
            step_us.append((time.perf_counter() - b) * 1e6)
        wall = time.perf_counter() - t0
        result["fmu_mpc_loop"] = dict(
            steps=args.loop_steps,
            steps_per_second=args.loop_steps / wall,
            real_time_factor=args.loop_steps * 0.02 / wall,
            solve_round_trip=stats(solve_us),
            step_round_trip=stats(step_us),
            model_latent_dim=34,
            horizon=cfg["horizon"],
        )
        text = json.dumps(result, indent=2)
        (out / "bench-python.json").write_text(text)
        print(text)
        return 0
    finally:
        c.close()
        for p in procs:
            try:
                p.stdin.close()
            except Exception:
                pass
        for p in procs:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()


if __name__ == "__main__":
    sys.exit(main())
