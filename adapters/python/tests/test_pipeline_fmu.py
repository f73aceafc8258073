"""The FMU pipeline driven from Python through the services, as the FMU scenario does it:
data collected through the FMU adapter, a Koopman model trained by `koopbridge serve trainer`,
fetched from the model store, and the FMU pendulum regulated by the MPC service (tiny budget)."""

from __future__ import annotations

import time

import numpy as np

import koopbridge
from conftest import Child, fmu_adapter_cmd, free_endpoint, koopbridge_binary_or_skip


def collect(c: koopbridge.Client, sim: str, windows: int, steps: int, seed: int):
    """Windows of SPEC data through the simulator: seeded reset, uniform u in ±8 held per step."""
    rng = np.random.default_rng(seed)
    xs, us = [], []
    for w in range(windows):
        x = [c.reset(sim, seed=seed * 100000 + w)]
        u = rng.uniform(-8, 8, size=(steps, 1))
        for k in range(steps):
            x.append(c.step(sim, u[k])[2])
        xs.append(x)
        us.append(u)
    return np.array(xs), np.array(us)


def test_collect_train_fetch_and_regulate_through_the_services(tmp_path, damped_fmu, session_id):
    exe = koopbridge_binary_or_skip()
    ep = free_endpoint()
    store = tmp_path / "store"
    serve = [str(exe), "serve", "trainer", "mpc", "models", "--session", session_id, "--id", "s0", "--store", str(store),
             "--state-dir", str(tmp_path / "state"), "--data-root", str(tmp_path), "--connect", ep]
    with koopbridge.Client(session=session_id, listen=[ep]) as c, \
            Child(fmu_adapter_cmd(damped_fmu, session_id, "pend", "--connect", ep), tmp_path / "adapter.log"), \
            Child(serve, tmp_path / "serve.log") as services:
        c.connect_sim("pend", timeout=30)
        paths = {}
        for split, n, seed in (("train", 48, 1), ("val", 16, 2), ("test", 16, 3)):
            x, u = collect(c, "pend", n, 15, seed)
            assert x.shape == (n, 16, 2) and u.shape == (n, 15, 1)
            paths[split] = str(tmp_path / f"{split}.npz")
            np.savez(paths[split], x=x, u=u)
        t_end = time.monotonic() + 30
        while True:
            try:
                job = c.submit_job("s0", "fmu-pend", paths["train"], paths["val"], paths["test"],
                                   config={"iterations": 60, "validate_every": 30, "hidden": [32, 32], "n_mult": 4, "batch": 16})
                break
            except koopbridge.BridgeTimeout:
                assert time.monotonic() < t_end, services.output()
        rec = c.wait_job("s0", job, timeout=300)
        assert rec["state"] == "done", rec
        assert np.isfinite(rec["metrics"]["test_prediction_error"])
        model = koopbridge.KoopmanModel.load(c.fetch_model("fmu-pend", str(tmp_path / "fetched")))
        assert (model.nx, model.nu, model.latent_dim) == (2, 1, 10)
        assert model.predict([-2.5, 0.1], np.zeros((15, 1))).shape == (15, 2)
        c.configure_mpc("s0", "fmu-pend", horizon=15, u_min=[-8.0], u_max=[8.0])
        x = c.reset("pend", x0=[-2.5, 0.1])
        for _ in range(40):
            sol = c.solve("s0", x, [0.0, 0.0], model="fmu-pend", nu=1)
            u = sol["u"][0]
            assert np.all(np.abs(u) <= 8.0 + 1e-9)
            x = c.step("pend", u)[2]
            assert np.all(np.isfinite(x))
