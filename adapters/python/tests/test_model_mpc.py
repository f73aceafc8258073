"""koopbridge.KoopmanModel and koopbridge.Mpc against independent numpy computations."""

from __future__ import annotations

import numpy as np
import pytest

import koopbridge


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    # A small untrained model, saved and loaded back: load() is what users call.
    m = koopbridge.KoopmanModel.init(nx=2, nu=1, hidden=[16, 16], n_mult=4, seed=3)
    d = tmp_path_factory.mktemp("model")
    m.save(str(d))
    return koopbridge.KoopmanModel.load(str(d))


def test_shapes_and_projection(model):
    n = model.latent_dim
    assert (model.nx, model.nu, n) == (2, 1, 2 + 8)
    assert model.A.shape == (n, n) and model.B.shape == (n, 1) and model.P.shape == (2, n)
    np.testing.assert_array_equal(model.P, np.eye(2, n))


def test_encode_keeps_x_and_is_batched(model):
    xs = np.random.default_rng(0).normal(size=(5, 2))
    z = model.encode(xs)
    assert z.shape == (5, model.latent_dim)
    np.testing.assert_array_equal(z[:, :2], xs)  # z = [x, ψ(x)]
    for i in range(5):
        np.testing.assert_allclose(model.encode(xs[i]), z[i], rtol=0, atol=1e-12)
    assert np.ptp(z[:, 2:]) > 0  # ψ is not constant


def test_predict_is_the_linear_rollout(model):
    rng = np.random.default_rng(1)
    x0, u = rng.normal(size=2), rng.normal(size=(7, 1))
    got = model.predict(x0, u)
    z = model.encode(x0)
    want = []
    for t in range(7):
        z = model.A @ z + model.B @ u[t]
        want.append(model.P @ z)
    np.testing.assert_allclose(got, np.array(want), rtol=1e-12, atol=1e-12)


def test_bad_arguments_are_value_errors(model, tmp_path):
    with pytest.raises(ValueError, match="nx = 2"):
        model.encode(np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        model.predict([np.nan, 0], np.zeros((2, 1)))
    with pytest.raises(OSError):
        koopbridge.KoopmanModel.load(str(tmp_path / "nowhere"))


def condensed(model, x0, horizon):
    """x_{1..H} = f + G u (stacked), from the model's matrices alone."""
    A, B, P = model.A, model.B, model.P
    z0 = model.encode(x0)
    nx, nu = model.nx, model.nu
    f = np.zeros(horizon * nx)
    G = np.zeros((horizon * nx, horizon * nu))
    Ak = np.eye(A.shape[0])
    for t in range(horizon):  # x_{t+1} = P A^{t+1} z0 + sum_j P A^{t-j} B u_j
        Ak = A @ Ak
        f[t * nx : (t + 1) * nx] = P @ Ak @ z0
        for j in range(t + 1):
            G[t * nx : (t + 1) * nx, j * nu : (j + 1) * nu] = P @ np.linalg.matrix_power(A, t - j) @ B
    return f, G


def test_mpc_matches_the_least_squares_optimum(model):
    H, r_w = 6, 0.1
    x0, ref = np.array([0.4, -0.2]), np.array([0.1, 0.0])
    f, G = condensed(model, x0, H)
    R = np.full(H, r_w)
    u_star = np.linalg.solve(G.T @ G + np.diag(R), G.T @ (np.tile(ref, H) - f))
    mpc = koopbridge.Mpc(model, horizon=H, r=[r_w], u_min=[-1e3], u_max=[1e3])
    sol = mpc.solve(x0, ref)
    assert sol["u"].shape == (H, 1) and sol["status"] == "solved"
    np.testing.assert_allclose(sol["u"].ravel(), u_star, rtol=1e-6, atol=1e-6)
    # A stacked reference (H, nx) equal to the held one gives the same plan.
    np.testing.assert_allclose(mpc.solve(x0, np.tile(ref, (H, 1)))["u"], sol["u"], atol=1e-9)


def test_error_state_mpc_is_the_least_squares_optimum_about_the_plan(model):
    # Cost Σ‖P(z_τ − ž_τ)‖² + r‖u − u_ff‖², ž the model's rollout of the plan from Φ(r_now):
    # its least-squares optimum in closed form, computed here with numpy.
    H, r_w = 6, 0.1
    x0, r_now, u_ff = np.array([0.4, -0.2]), np.array([0.3, 0.1]), 0.3 * np.sin(np.arange(6.0))
    f, G = condensed(model, x0, H)
    f_plan, _ = condensed(model, r_now, H)
    plan = f_plan + G @ u_ff
    R = np.full(H, r_w)
    u_star = np.linalg.solve(G.T @ G + np.diag(R), G.T @ (plan - f) + R * u_ff)
    mpc = koopbridge.Mpc(model, horizon=H, r=[r_w], u_min=[-1e3], u_max=[1e3])
    sol = mpc.solve(x0, r_now, feedforward=u_ff.reshape(H, 1))
    np.testing.assert_allclose(sol["u"].ravel(), u_star, rtol=1e-6, atol=1e-6)
    with pytest.raises(ValueError, match="feedforward"):
        mpc.solve(x0, r_now, feedforward=u_ff[:5])
    with pytest.raises(ValueError, match="with a feedforward"):
        mpc.solve(x0, np.tile(r_now, (H, 1)), feedforward=u_ff)


def test_mpc_respects_bounds_and_beats_clamping(model):
    H = 6
    x0, ref = np.array([1.5, -1.0]), np.array([0.0, 0.0])
    f, G = condensed(model, x0, H)

    def cost(u):
        e = f + G @ u - np.tile(ref, H)
        return e @ e

    free = np.linalg.lstsq(G, np.tile(ref, H) - f, rcond=None)[0]
    bound = 0.5 * np.max(np.abs(free))
    sol = koopbridge.Mpc(model, horizon=H, u_min=[-bound], u_max=[bound], solver="clarabel").solve(x0, ref)
    u = sol["u"].ravel()
    assert np.all(np.abs(u) <= bound + 1e-9)
    assert cost(u) <= cost(np.clip(free, -bound, bound)) + 1e-9


def test_mpc_configuration_errors(model):
    with pytest.raises(ValueError, match="MPC configuration"):
        koopbridge.Mpc(model, horizn=3)
    mpc = koopbridge.Mpc(model, horizon=4)
    with pytest.raises(ValueError, match="reference: expected 2 .* or 8"):
        mpc.solve([0.0, 0.0], [0.0, 0.0, 0.0])


def test_vectors_must_be_one_dimensional(model):
    with pytest.raises(ValueError, match="expected a 1-D array, got 2-D"):
        model.predict([[0.1, 0.2]], np.zeros((3, 1)))
    sys_ = koopbridge.ReferenceSystem("damped-pendulum")
    np.testing.assert_array_equal(sys_.step([0.1, 0.2], 0.0), sys_.step(np.array([0.1, 0.2]), [0.0]))


def test_a_normalised_model_predicts_in_raw_units(model, tmp_path):
    # A model declared to work in z-scored units (what `koopbridge train --normalise` saves):
    # predict normalises x0 and u, rolls out in the model's coordinates and maps back.
    import json

    model.save(str(tmp_path))
    cfg = json.loads((tmp_path / "config.json").read_text())
    norm = {"x_mean": [0.5, -2.0], "x_std": [3.0, 0.2], "u_mean": [1.5], "u_std": [4.0]}
    cfg["normalisation"] = norm
    (tmp_path / "config.json").write_text(json.dumps(cfg))
    m = koopbridge.KoopmanModel.load(str(tmp_path))
    assert model.normalisation is None
    assert m.normalisation == norm
    rng = np.random.default_rng(2)
    x0, u = rng.normal(size=2) * 3, rng.normal(size=(6, 1)) * 4
    xm, xs = np.array(norm["x_mean"]), np.array(norm["x_std"])
    z = m.encode((x0 - xm) / xs)
    want = []
    for t in range(6):
        z = m.A @ z + m.B @ ((u[t] - norm["u_mean"][0]) / norm["u_std"][0])
        want.append(xm + xs * (m.P @ z))
    np.testing.assert_allclose(m.predict(x0, u), np.array(want), rtol=1e-12, atol=1e-12)
    # A normalisation of the wrong size is refused when the model is loaded.
    cfg["normalisation"] = {**norm, "u_std": [1.0, 2.0]}
    (tmp_path / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(Exception, match="normalisation"):
        koopbridge.KoopmanModel.load(str(tmp_path))
