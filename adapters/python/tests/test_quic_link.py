"""Python participants on the secure QUIC link of `config/` (issue 29): behind `koopbridge router`
with `router-quic.json5` (mutual authentication), a plain `eclipse-zenoh` client and the SDK's
`koopbridge.Client` with `client-quic.json5` reach a simulator and step it, and a plain client
without a certificate gets no session. Certificates are made here with the `openssl` CLI."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import time
from pathlib import Path

import pytest
import zenoh

import koopbridge
from conftest import ROOT, Child, koopbridge_binary_or_skip

NAMES = ["router", "operator", "sim-host"]


def make_pki(d: Path) -> Path:
    """A test CA and EC P-256 certificates for NAMES (SAN localhost, 127.0.0.1) in `d`."""
    if shutil.which("openssl") is None:
        pytest.skip("the openssl CLI is not installed (needed to make test certificates)")
    d.mkdir(parents=True, exist_ok=True)
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes"]

    def run(*a: str) -> None:
        subprocess.run(["openssl", *a], cwd=d, check=True, capture_output=True)

    run("req", "-x509", "-days", "2", "-subj", "/CN=koopbridge-test-ca", *ec, "-keyout", "ca.key", "-out", "ca.pem")
    (d / "leaf.ext").write_text(
        "subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n"
        "keyUsage=digitalSignature\nextendedKeyUsage=serverAuth,clientAuth\n"
    )
    for cn in NAMES:
        run("req", "-subj", f"/CN={cn}", *ec, "-keyout", f"{cn}.key", "-out", f"{cn}.csr")
        run("x509", "-req", "-in", f"{cn}.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
            "-days", "2", "-extfile", "leaf.ext", "-out", f"{cn}.pem")  # fmt: skip
    return d


def config(example: str, pki: Path, identity: str, out: Path, drop: tuple[str, ...] = ()) -> Path:
    """`config/{example}` with its certificate paths in `pki` (own certificate `{identity}`)."""
    lines = (ROOT / "config" / example).read_text().splitlines()
    text = "\n".join(
        line.replace("/etc/koopbridge/tls/client.", f"{pki}/{identity}.").replace("/etc/koopbridge/tls", str(pki))
        for line in lines
        if not any(d in line for d in drop)
    )
    assert "/etc/koopbridge" not in text
    p = out / f"{example.removesuffix('.json5')}-{identity}.json5"
    p.write_text(text)
    return p


def quic_endpoint() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"quic/localhost:{s.getsockname()[1]}"


def plain_session(cfg: Path, ep: str) -> zenoh.Session:
    conf = zenoh.Config.from_file(str(cfg))
    conf.insert_json5("connect/endpoints", json.dumps([ep]))
    return zenoh.open(conf)


def test_python_participants_join_the_quic_router(tmp_path, session_id):
    exe = koopbridge_binary_or_skip()
    pki = make_pki(tmp_path / "pki")
    ep = quic_endpoint()
    router_cmd = [str(exe), "router", "--listen", ep, "--stdin-lifeline",
                  "--zenoh-config", str(config("router-quic.json5", pki, "router", tmp_path))]  # fmt: skip
    sim_cmd = [str(exe), "sim", "--env", "damped-pendulum", "--id", "pend", "--session", session_id,
               "--mode", "client", "--connect", ep, "--stdin-lifeline",
               "--zenoh-config", str(config("client-quic.json5", pki, "sim-host", tmp_path))]  # fmt: skip
    op_cfg = config("client-quic.json5", pki, "operator", tmp_path)
    with Child(router_cmd, tmp_path / "router.log"), Child(sim_cmd, tmp_path / "sim.log"):
        # The plain eclipse-zenoh client, with the operator's certificate, over QUIC.
        deadline = time.monotonic() + 60
        while True:
            try:
                s = plain_session(op_cfg, ep)
                break
            except zenoh.ZError:
                assert time.monotonic() < deadline, "no QUIC session with the router"
                time.sleep(0.2)
        try:
            info = None
            while info is None and time.monotonic() < deadline:
                for r in s.get(f"koopbridge/{session_id}/sim/pend/info", timeout=2.0):
                    if r.ok is not None:
                        info = json.loads(r.ok.payload.to_bytes())
                time.sleep(0.1)
            assert info is not None and info["state_names"] == ["theta", "theta_dot"], info
        finally:
            s.close()
        # Without a client certificate: no session.
        no_cert = config("client-quic.json5", pki, "nocert", tmp_path,
                         drop=("connect_certificate", "connect_private_key", "enable_mtls", "Present the"))  # fmt: skip
        with pytest.raises(zenoh.ZError):
            plain_session(no_cert, ep).close()
        # The SDK's client, same file: steps the simulator.
        with koopbridge.Client(session=session_id, connect=[ep], mode="client", zenoh_config=str(op_cfg)) as c:
            c.connect_sim("pend", timeout=60.0)
            c.reset("pend", x0=[0.3, 0.0])
            k, _, x = c.step("pend", [0.1])
            assert k == 1 and len(x) == 2
