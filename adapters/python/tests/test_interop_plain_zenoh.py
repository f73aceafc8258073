"""Interoperability: a plain `eclipse-zenoh` client, without the koopbridge SDK, follows
PROTOCOL.md to step the FMU adapter and to get an MPC solve from `koopbridge serve mpc`.
Everything on the wire below is encoded and decoded here with `struct` and `json` only."""

from __future__ import annotations

import json
import struct
import time

import numpy as np
import zenoh

import koopbridge
from conftest import Child, fmu_adapter_cmd, free_endpoint, koopbridge_binary_or_skip

# ---- PROTOCOL.md §4, written from the document ----


def step_request(k: int, u) -> bytes:
    return struct.pack("<2sBBQI", b"KB", 1, 0x01, k, len(u)) + struct.pack(f"<{len(u)}d", *u)


def decode_vec(b: bytes, off: int):
    (n,) = struct.unpack_from("<I", b, off)
    return list(struct.unpack_from(f"<{n}d", b, off + 4)), off + 4 + 8 * n


def step_reply(b: bytes):
    assert b[:4] == b"KB\x01\x02", b[:4]
    k, t = struct.unpack_from("<Qd", b, 4)
    x, end = decode_vec(b, 20)
    assert end == len(b)
    return k, t, x


def solve_request(model: str, x, reference) -> bytes:
    name = model.encode()
    out = struct.pack("<2sBBH", b"KB", 1, 0x05, len(name)) + name
    for v in (x, reference):
        out += struct.pack("<I", len(v)) + struct.pack(f"<{len(v)}d", *v)
    return out


def solve_reply(b: bytes):
    assert b[:4] == b"KB\x01\x06", b[:4]
    status, iterations, ns = struct.unpack_from("<BIQ", b, 4)
    u, end = decode_vec(b, 17)
    assert end == len(b)
    return status, iterations, ns, u


def test_encoders_reproduce_the_golden_vectors():
    assert step_request(3, [1.5]).hex() == "4b420101" "0300000000000000" "01000000" "000000000000f83f"
    assert solve_request("ab", [1.5], []).hex() == "4b420105" "0200" "6162" "01000000" "000000000000f83f" "00000000"
    gold = bytes.fromhex("4b420102" "0400000000000000" "7b14ae47e17a943f" "02000000" "000000000000f83f" "00000000000000c0")
    assert step_reply(gold) == (4, 0.02, [1.5, -2.0])
    gold = bytes.fromhex("4b420106" "01" "09000000" "0001000000000000" "01000000" "00000000000000c0")
    assert solve_reply(gold) == (1, 9, 256, [-2.0])


# ---- a plain Zenoh session ----


def open_plain(connect: str):
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([connect]))
    return zenoh.open(conf)


def get_one(s, key: str, payload: bytes | None = None, timeout: float = 5.0):
    """One query; returns (ok, bytes) of its first reply, or None when nobody answered."""
    kw = dict(timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE)
    if payload is not None:
        kw["payload"] = payload
    for reply in s.get(key, **kw):
        if reply.ok is not None:
            return True, reply.ok.payload.to_bytes()
        return False, reply.err.payload.to_bytes()
    return None


def get_until_answered(s, key: str, deadline_s: float = 20.0):
    t_end = time.monotonic() + deadline_s
    while time.monotonic() < t_end:
        r = get_one(s, key, timeout=1.0)
        if r is not None:
            return r
        time.sleep(0.05)
    raise AssertionError(f"no reply from {key}")


def test_plain_zenoh_client_steps_the_fmu_adapter(tmp_path, damped_fmu, session_id):
    ep = free_endpoint()
    root = f"koopbridge/{session_id}/sim/fmu0"
    ref = koopbridge.ReferenceSystem("damped-pendulum")
    with Child(fmu_adapter_cmd(damped_fmu, session_id, "fmu0", "--listen", ep), tmp_path / "adapter.log"):
        s = open_plain(ep)
        try:
            ok, body = get_until_answered(s, f"{root}/info")
            info = json.loads(body)
            assert ok and info["protocol_version"] == 1 and info["state_names"] == ["theta", "omega"]
            ok, body = get_one(s, f"{root}/reset", json.dumps({"x0": [-2.5, 0.1]}).encode())
            assert ok and step_reply(body) == (0, 0.0, [-2.5, 0.1])
            x = [-2.5, 0.1]
            for k in range(10):
                u = [np.sin(k)]
                ok, body = get_one(s, f"{root}/step", step_request(k, u))
                assert ok
                kk, t, nxt = step_reply(body)
                assert kk == k + 1 and abs(t - 0.02 * (k + 1)) < 1e-12
                np.testing.assert_allclose(nxt, ref.step(x, u), atol=1e-7)
                x = nxt
            # A retried step k = 9 with the same u gets the cached reply, not a second step...
            ok, again = get_one(s, f"{root}/step", step_request(9, [np.sin(9)]))
            assert ok and again == body
            # ...and errors are JSON {"code", "message"} error replies.
            ok, err = get_one(s, f"{root}/step", step_request(3, [0.0]))
            assert not ok and json.loads(err)["code"] == "conflict"  # k = 3 was taken with another u
            ok, err = get_one(s, f"{root}/step", step_request(50, [0.0]))
            assert not ok and json.loads(err)["code"] == "out_of_order"
            ok, err = get_one(s, f"{root}/step", b"KB\x01\x01\x00")
            assert not ok and json.loads(err)["code"] == "bad_request"
        finally:
            s.close()


def test_plain_zenoh_client_gets_an_mpc_solve(tmp_path, session_id):
    exe = koopbridge_binary_or_skip()
    store = tmp_path / "store"
    model = koopbridge.KoopmanModel.init(nx=2, nu=1, hidden=[16, 16], n_mult=4, seed=5)
    model.save(str(store / "pend"))
    ep = free_endpoint()
    cmd = [str(exe), "serve", "mpc", "--session", session_id, "--id", "m0", "--store", str(store),
           "--state-dir", str(tmp_path / "state"), "--listen", ep]
    with Child(cmd, tmp_path / "serve.log") as child:
        s = open_plain(ep)
        try:
            cfg = {"horizon": 8, "u_min": [-8.0], "u_max": [8.0]}
            t_end = time.monotonic() + 30
            r = None
            while r is None and time.monotonic() < t_end:
                r = get_one(s, f"koopbridge/{session_id}/mpc/m0/configure", json.dumps({"model": "pend", "mpc": cfg}).encode(), 2.0)
            assert r is not None and r[0], (r, child.output())
            reply = json.loads(r[1])
            assert (reply["nx"], reply["nu"], reply["horizon"]) == (2, 1, 8)
            x, ref = [-2.5, 0.1], [0.0, 0.0]
            ok, body = get_one(s, f"koopbridge/{session_id}/mpc/m0/solve", solve_request("pend", x, ref))
            assert ok, body
            status, iterations, ns, u = solve_reply(body)
            assert status in (0, 3) and len(u) == 8 and ns > 0
            # The same plan as an in-process solve with the same model and settings.
            want = koopbridge.Mpc(model, **cfg).solve(x, ref)["u"].ravel()
            np.testing.assert_allclose(u, want, atol=1e-9)
            ok, err = get_one(s, f"koopbridge/{session_id}/mpc/m0/solve", solve_request("pend", [1.0], ref))
            assert not ok and json.loads(err)["code"] in ("dimension", "bad_request")
        finally:
            s.close()
