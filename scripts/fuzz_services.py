"""Bounded fuzzing of a live koopbridge session with a plain eclipse-zenoh client: N queries with
random, mutated, truncated and oversized payloads to every queryable (simulator info/reset/step,
trainer jobs, MPC configure/solve/attach, recorder, model store, recordings). Counts replies that
are missing, error replies that are not typed (`{"code", "message"}` with a known code),
`internal` errors, processes that died, and the resident memory of each process before, at every
tenth of the run, right after it and after a second of idle. Exit code 0 only with 0 dead, 0
missing and 0 untyped.

Usage: python scripts/fuzz_services.py --exe target/release/koopbridge --queries N [--seed S]
(scripts/fuzz-services.sh N runs it with the repository's venv and binary)."""

from __future__ import annotations

import argparse
import json
import os
import random
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import zenoh

CODES = {
    "bad_request", "version_mismatch", "too_large", "dimension", "out_of_order", "conflict",
    "sim_failure", "not_found", "busy", "unsupported", "internal", "forbidden",
}  # fmt: skip


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return -1


def step_request(k: int, u: list[float]) -> bytes:
    return struct.pack("<2sBBQI", b"KB", 1, 0x01, k, len(u)) + struct.pack(f"<{len(u)}d", *u)


def solve_request(model: str, x: list[float], ref: list[float], feedforward: list[float] | None = None) -> bytes:
    """A `SolveRequest`: type 0x05, or 0x08 with a feed-forward (PROTOCOL.md §4)."""
    name = model.encode()
    out = struct.pack("<2sBBH", b"KB", 1, 0x08 if feedforward else 0x05, len(name)) + name
    for v in (x, ref, *([feedforward] if feedforward else [])):
        out += struct.pack("<I", len(v)) + struct.pack(f"<{len(v)}d", *v)
    return out


# Valid or nearly valid requests per queryable leaf; the fuzzer mutates and truncates them.
SEEDS = {
    "info": [b""],
    "reset": [b"{}", b'{"seed": 3}', b'{"x0": [0.1, 0.2]}'],
    "step": [step_request(0, [0.5]), step_request(7, [1.0, 2.0])],
    "jobs": [
        b'{"model": "m", "train": {"path": "train.npz"}, "val": {"path": "val.npz"}}',
        b'{"model": "m", "train": {"recording": "r"}, "val": {"recording": "r"}, "config": {"iterations": 1}}',
        b"",
    ],
    "job": [b"", b'{"cancel": true}'],
    "configure": [b'{"model": "nope"}', b'{"model": "m", "mpc": {"horizon": 5}}'],
    "solve": [solve_request("", [0.1, 0.2], [0.0, 0.0]), solve_request("m", [0.0], []),
              solve_request("", [0.1, 0.2], [0.0, 0.0], [0.5] * 5)],
    "attach": [b'{"sim": "sim0", "model": "m", "reference": [0, 0]}', b'{"sim": "sim0", "detach": true}'],
    "record": [b'{"action": "start", "sim": "sim0"}', b'{"action": "stop", "sim": "sim0", "name": "r"}'],
    "models": [b""],
    "data": [b""],
}


def keys(session: str) -> dict[str, str]:
    r = f"koopbridge/{session}"
    return {
        "info": f"{r}/sim/sim0/info",
        "reset": f"{r}/sim/sim0/reset",
        "step": f"{r}/sim/sim0/step",
        "jobs": f"{r}/trainer/main/jobs",
        "job": f"{r}/trainer/main/jobs/j0000",
        "configure": f"{r}/mpc/main/configure",
        "solve": f"{r}/mpc/main/solve",
        "attach": f"{r}/mpc/main/attach",
        "record": f"{r}/recorder/main/record",
        "models": f"{r}/models/nope",
        "data": f"{r}/data/nope",
    }


def mutate(rng: random.Random, b: bytes) -> bytes:
    """One of: random bytes, a truncation, byte flips, an insertion, an oversized payload."""
    kind = rng.random()
    if kind < 0.15 or not b:
        return rng.randbytes(rng.randrange(0, 300))
    if kind < 0.35:
        return b[: rng.randrange(0, len(b))]
    if kind < 0.75:
        m = bytearray(b)
        for _ in range(rng.randrange(1, 5)):
            m[rng.randrange(len(m))] = rng.randrange(256)
        return bytes(m)
    if kind < 0.97:
        i = rng.randrange(len(b) + 1)
        return b[:i] + rng.randbytes(rng.randrange(1, 40)) + b[i:]
    return b + rng.randbytes(rng.choice([70_000, 1_100_000, 17_000_000]))


def classify(replies: list) -> str:
    """`ok`, `typed`, `internal`, `untyped` or `missing` for the replies of one query."""
    if not replies:
        return "missing"
    r = replies[0]
    if r.ok is not None:
        return "ok"
    try:
        e = json.loads(r.err.payload.to_bytes())
        code = e.get("code")
        if code in CODES and isinstance(e.get("message"), str):
            return "internal" if code == "internal" else "typed"
    except (ValueError, AttributeError):
        pass
    return "untyped"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", required=True)
    ap.add_argument("--queries", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=10.0, help="seconds a query may wait for its reply")
    args = ap.parse_args()
    rng = random.Random(args.seed)
    session = f"fuzz{os.getpid()}"
    ep = f"tcp/127.0.0.1:{free_port()}"
    work = Path(tempfile.mkdtemp(prefix="kb-fuzz-"))
    common = ["--session", session, "--stdin-lifeline"]
    procs = {
        "services": subprocess.Popen(
            [args.exe, "serve", *common, "--listen", ep, "--store", str(work / "models"), "--state-dir", str(work / "state")],
            stdin=subprocess.PIPE, stdout=open(work / "services.log", "wb"), stderr=subprocess.STDOUT, cwd=work,
        ),
    }  # fmt: skip
    time.sleep(1.0)
    procs["sim"] = subprocess.Popen(
        [args.exe, "sim", "--env", "damped-pendulum", "--id", "sim0", *common, "--connect", ep],
        stdin=subprocess.PIPE, stdout=open(work / "sim.log", "wb"), stderr=subprocess.STDOUT, cwd=work,
    )  # fmt: skip
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([ep]))
    s = zenoh.open(conf)
    k = keys(session)

    def query(key: str, payload: bytes) -> list:
        return list(s.get(key, payload=payload, timeout=args.timeout, consolidation=zenoh.ConsolidationMode.NONE))

    deadline = time.monotonic() + 60
    while not [r for r in query(k["info"], b"") if r.ok is not None] or classify(query(k["jobs"], b"")) == "missing":
        if time.monotonic() > deadline:
            print("fuzz: the session did not come up", file=sys.stderr)
            return 2
        time.sleep(0.2)
    rss0 = {n: rss_kib(p.pid) for n, p in procs.items()}
    counts = {c: 0 for c in ["ok", "typed", "internal", "untyped", "missing"]}
    by_leaf: dict[str, dict[str, int]] = {}
    examples: list[str] = []
    t0 = time.monotonic()
    leaves = list(SEEDS)
    samples: dict[str, list[int]] = {n: [] for n in procs}
    every = max(1, args.queries // 10)
    for i in range(args.queries):
        if i % every == 0:
            for n, p in procs.items():
                samples[n].append(rss_kib(p.pid) if p.poll() is None else -1)
        leaf = leaves[i % len(leaves)]
        payload = mutate(rng, rng.choice(SEEDS[leaf]))
        c = classify(query(k[leaf], payload))
        counts[c] += 1
        by_leaf.setdefault(leaf, {}).setdefault(c, 0)
        by_leaf[leaf][c] += 1
        if c in ("untyped", "missing", "internal") and len(examples) < 10:
            examples.append(f"{leaf} {c}: {payload[:60]!r} ({len(payload)} bytes)")
        if any(p.poll() is not None for p in procs.values()):
            break
    elapsed = time.monotonic() - t0
    dead = [n for n, p in procs.items() if p.poll() is not None]
    rss1 = {n: (rss_kib(p.pid) if p.poll() is None else -1) for n, p in procs.items()}
    # Again after a second without queries: what the processes keep, not what is in flight.
    time.sleep(1.0)
    rss_idle = {n: (rss_kib(p.pid) if p.poll() is None else -1) for n, p in procs.items()}
    s.close()
    for p in procs.values():
        if p.poll() is None:
            p.stdin.close()
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
    report = {
        "queries": sum(counts.values()),
        "seconds": round(elapsed, 1),
        **counts,
        "dead": dead,
        "rss_kib_before": rss0,
        "rss_kib_after": rss1,
        "rss_kib_after_idle": rss_idle,
        "rss_kib_every_tenth": samples,
        "by_leaf": by_leaf,
        "examples": examples,
        "logs": str(work),
    }
    print(json.dumps(report, indent=1))
    return 0 if not dead and counts["missing"] == 0 and counts["untyped"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
