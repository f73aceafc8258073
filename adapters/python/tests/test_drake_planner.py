"""The Drake planner service as a child process (`python -m koopbridge.adapters.drake_planner`),
queried by a plain `eclipse-zenoh` client as PROTOCOL.md says: a plan comes back sampled at the
requested dt; infeasible goals, NaN, wrong lengths, out-of-limits goals and a request while
another plan runs are typed error replies, and the planner keeps serving."""

from __future__ import annotations

import json
import sys
import threading
import time

import numpy as np
from test_interop_plain_zenoh import get_one, open_plain

from conftest import Child, free_endpoint


def _plan(s, key, body: bytes, timeout: float = 30.0):
    r = get_one(s, key, body, timeout=timeout)
    assert r is not None, "no reply"
    ok, payload = r
    return ok, json.loads(payload)


def _wait_ready(s, key, deadline_s=60.0):
    """Queries with an empty body until the planner answers (bad_request: it is up)."""
    t_end = time.monotonic() + deadline_s
    while time.monotonic() < t_end:
        r = get_one(s, key, b"", timeout=1.0)
        if r is not None:
            return r
        time.sleep(0.1)
    raise AssertionError(f"no reply from {key}")


def test_planner_service_plans_and_answers_bad_input(tmp_path, session_id):
    ep = free_endpoint()
    key = f"koopbridge/{session_id}/planner/p0/plan"
    cmd = [sys.executable, "-m", "koopbridge.adapters.drake_planner", "--session", session_id, "--id", "p0", "--listen", ep]
    with Child(cmd, tmp_path / "planner.log") as child:
        s = open_plain(ep)
        try:
            ok, err = _wait_ready(s, key)
            assert not ok and json.loads(err)["code"] == "bad_request"
            start, goal = [0.0] * 7, [0.5, 0.4, 0.0, 0.8, 0.0, 0.5, 0.0]
            ok, plan = _plan(s, key, json.dumps(dict(start=start, goal=goal, dt=0.01)).encode())
            assert ok, plan
            t, q, qd = np.array(plan["t"]), np.array(plan["q"]), np.array(plan["qd"])
            assert q.shape == qd.shape == (len(t), 7) and np.allclose(np.diff(t)[:-1], 0.01)
            np.testing.assert_allclose(q[0], start, atol=1e-6)
            np.testing.assert_allclose(q[-1], goal, atol=1e-6)
            assert [p["name"] for p in plan["passes"]] == ["kinematic", "collision"]

            def ask(body):
                ok, reply = _plan(s, key, json.dumps(body).encode() if isinstance(body, dict) else body)
                assert not ok, reply
                return reply["code"], reply["message"]

            code, msg = ask(dict(start=start, goal=[0.0, 2.3, 0, 0, 0, 0, 0], dt=0.01))
            assert code == "infeasible" and "pass 'collision'" in msg
            code, msg = ask(json.dumps(dict(start=start, goal=[float("nan")] * 7, dt=0.01)).encode())
            assert code == "bad_request" and "invalid JSON" in msg  # NaN is not JSON
            code, msg = ask(dict(start=start, goal=[0.0] * 6, dt=0.01))
            assert code == "dimension" and "'goal' has 6 values" in msg
            code, msg = ask(dict(start=start, goal=[0, 3.0, 0, 0, 0, 0, 0], dt=0.01))
            assert code == "bad_request" and "joint 2" in msg and "outside its limits" in msg
            code, msg = ask(dict(start=start, goal=goal, dt=0.0))
            assert code == "bad_request" and "dt must be positive" in msg
            code, msg = ask(dict(start=start, goal=goal, dt=0.01, speed=2))
            assert code == "bad_request" and "unknown field 'speed'" in msg

            # Two requests at once: one is planned, the other is refused with busy.
            replies = []
            far = dict(start=start, goal=[2.0, 0.9, -1.5, 1.6, 1.0, -1.2, 2.0], dt=0.01)
            threads = [threading.Thread(target=lambda: replies.append(_plan(s, key, json.dumps(far).encode()))) for _ in range(2)]
            for th in threads:
                th.start()
            for th in threads:
                th.join()
            codes = sorted("ok" if ok else r["code"] for ok, r in replies)
            assert codes == ["busy", "ok"], replies
            # ...and it keeps serving.
            ok, plan = _plan(s, key, json.dumps(dict(start=goal, goal=start, dt=0.05)).encode())
            assert ok and np.allclose(plan["q"][-1], start, atol=1e-6)
        finally:
            s.close()
        assert child.p.poll() is None, child.output()
