"""koopbridge.Client against the Rust services (`koopbridge serve mpc models`): fetching a model
from the model store, configuring the MPC service and solving through it."""

from __future__ import annotations

import numpy as np
import pytest

import koopbridge
from conftest import Child, free_endpoint, koopbridge_binary
from koopbridge.client import parse_model_archive


def test_model_archive_parser_rejects_bad_archives():
    with pytest.raises(koopbridge.KoopbridgeError, match="KBM1"):
        parse_model_archive(b"nope")
    import json
    import struct

    header = json.dumps({"name": "m", "files": [{"name": "../evil", "size": 1}]}).encode()
    with pytest.raises(koopbridge.KoopbridgeError, match="unsafe file name"):
        parse_model_archive(b"KBM1" + struct.pack("<I", len(header)) + header + b"x")
    header = json.dumps({"name": "m", "files": [{"name": "a", "size": 5}]}).encode()
    with pytest.raises(koopbridge.KoopbridgeError, match="truncated file a"):
        parse_model_archive(b"KBM1" + struct.pack("<I", len(header)) + header + b"xy")


def test_fetch_configure_and_solve_through_the_services(tmp_path, session_id):
    exe = koopbridge_binary()
    if exe is None:
        pytest.skip("the koopbridge CLI is not built (cargo build --release); scripts/test.sh builds it")
    store = tmp_path / "store"
    model = koopbridge.KoopmanModel.init(nx=2, nu=1, hidden=[32, 32], n_mult=4, seed=9)
    model.save(str(store / "pend"))
    ep = free_endpoint()
    cmd = [str(exe), "serve", "mpc", "models", "--session", session_id, "--id", "s0", "--store", str(store),
           "--state-dir", str(tmp_path / "state"), "--listen", ep]
    with Child(cmd, tmp_path / "serve.log") as child, koopbridge.Client(session=session_id, connect=[ep]) as c:
        import time

        t_end = time.monotonic() + 30
        while True:
            try:
                got = c.fetch_model("pend", str(tmp_path / "fetched"))
                break
            except koopbridge.BridgeTimeout:
                assert time.monotonic() < t_end, child.output()
        fetched = koopbridge.KoopmanModel.load(got)
        np.testing.assert_array_equal(fetched.A, model.A)
        np.testing.assert_array_equal(fetched.encode([0.3, -0.2]), model.encode([0.3, -0.2]))
        with pytest.raises(koopbridge.RemoteError) as e:
            c.fetch_model("absent", str(tmp_path / "absent"))
        assert e.value.code == "not_found"
        assert not (tmp_path / "absent").exists()
        reply = c.configure_mpc("s0", "pend", horizon=10, u_min=[-8.0], u_max=[8.0])
        assert (reply["nx"], reply["nu"], reply["horizon"]) == (2, 1, 10)
        sol = c.solve("s0", [-2.5, 0.1], [0.0, 0.0], model="pend", nu=1)
        want = koopbridge.Mpc(model, horizon=10, u_min=[-8.0], u_max=[8.0]).solve([-2.5, 0.1], [0.0, 0.0])
        assert sol["u"].shape == (10, 1) and sol["status"] in ("solved", "inaccurate")
        np.testing.assert_allclose(sol["u"], want["u"], atol=1e-9)
        with pytest.raises(koopbridge.RemoteError) as e:
            c.solve("s0", [1.0], [0.0, 0.0], model="pend")
        assert e.value.code in ("dimension", "bad_request")
