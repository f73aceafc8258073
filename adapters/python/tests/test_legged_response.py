"""The legged input-response diagnosis (koopbridge_experiments.legged_response) against closed forms:
a linear simulator's central differences are A^(h-1)·B exactly (one-sided at a bound), a Koopman
model's response is P·A^(h-1)·B of its own matrices, the agreement figures of a scaled copy are
known, and the constant share drops when the response changes with the state."""

from __future__ import annotations

import numpy as np
import pytest

from koopbridge import KoopmanModel
from koopbridge_experiments.legged_response import ResponseSample, main, model_response, sim_response, summarise


class LinearSim:
    """x⁺ = A x + B clip(u): a simulator whose response is known in closed form."""

    def __init__(self, A: np.ndarray, B: np.ndarray, lo: np.ndarray, hi: np.ndarray):
        self.A, self.B, self.u_lo, self.u_hi = A, B, lo, hi
        self.x = np.zeros(len(A))

    def reset(self, x0: np.ndarray) -> np.ndarray:
        self.x = np.array(x0, float)
        return self.x

    def step(self, u: np.ndarray) -> np.ndarray:
        self.x = self.A @ self.x + self.B @ np.clip(u, self.u_lo, self.u_hi)
        return self.x.copy()


def _powers(A: np.ndarray, B: np.ndarray, H: int) -> np.ndarray:
    out, M = [], B.copy()
    for _ in range(H):
        out.append(M.copy())
        M = A @ M
    return np.array(out)


def test_sim_response_is_the_closed_form_and_one_sided_at_a_bound() -> None:
    rng = np.random.default_rng(3)
    A = 0.5 * rng.normal(size=(4, 4)) / 2
    B = rng.normal(size=(4, 2))
    sim = LinearSim(A, B, lo=np.array([-1.0, -1.0]), hi=np.array([1.0, 0.2]))
    U = np.array([[0.3, 0.19]] + [[0.0, 0.0]] * 5)  # input 1 sits 0.01 under its bound
    G, nominal = sim_response(sim, rng.normal(size=4), U, delta=0.05)
    np.testing.assert_allclose(G, _powers(A, B, 6), rtol=1e-9, atol=1e-12)
    assert nominal.shape == (6, 4)
    pinned = U.copy()
    pinned[0, 1] = 5.0  # both sides clipped to the same bound: no difference can be made
    G, _ = sim_response(sim, np.zeros(4), pinned, delta=0.05)
    assert np.all(np.isnan(G[:, :, 1])) and np.all(np.isfinite(G[:, :, 0]))


def test_model_response_is_P_A_B_of_the_model() -> None:
    m = KoopmanModel.init(3, 2, hidden=[8], n_mult=2, seed=5)
    A, B, P = np.asarray(m.A), np.asarray(m.B), np.asarray(m.P)
    H = 4
    G, nominal = model_response(m, np.array([0.1, -0.2, 0.3]), np.zeros((H, 2)), 0.01, np.full(2, -9.0), np.full(2, 9.0))
    want = np.array([P @ M for M in _powers(A, B, H)])
    np.testing.assert_allclose(G, want, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(nominal, np.asarray(m.predict([0.1, -0.2, 0.3], np.zeros((H, 2))))[-H:], rtol=1e-12)


def _sample(G_sim: np.ndarray, G_model: np.ndarray) -> ResponseSample:
    H, nx, _ = G_sim.shape
    z = np.zeros((H, nx))
    return ResponseSample(0, 0, np.zeros(nx), G_sim, G_model, z, z + 0.01)


def test_summary_of_a_scaled_copy_and_of_a_state_dependent_response() -> None:
    rng = np.random.default_rng(1)
    G = rng.normal(size=(3, 5, 2))
    row = summarise([_sample(G, 0.5 * G), _sample(G, 0.5 * G)], slice(1, 4), np.ones(5))["horizons"][0]
    assert row["joints"]["projection"] == pytest.approx(0.5)
    assert row["joints"]["cosine"] == pytest.approx(1.0)
    assert row["joints"]["norm_ratio"] == pytest.approx(0.5)
    assert row["constant_share_joints"] == pytest.approx(1.0)  # the same response at every state
    assert row["nominal_joint_error_rad"] == pytest.approx(0.01)
    flipped = summarise([_sample(G, G), _sample(-G, G)], slice(1, 4), np.ones(5))["horizons"][0]
    assert flipped["constant_share_joints"] == pytest.approx(0.0)  # opposite responses: their mean explains none
    assert flipped["joints"]["projection"] == pytest.approx(0.0)


def test_bad_arguments_exit_2(tmp_path) -> None:
    assert main(["--model", str(tmp_path), "--delta", "0", "--out", str(tmp_path / "o")]) == 2
    assert main(["--model", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
