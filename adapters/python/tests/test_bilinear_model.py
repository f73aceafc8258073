"""koopbridge.BilinearModel: save/load, and its forecast against an independent numpy rollout."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import koopbridge


def _set_n(model_dir: Path, values: np.ndarray) -> None:
    """Overwrites the N tensor (F64) of a saved model's safetensors file in place."""
    path = model_dir / "model.safetensors"
    raw = path.read_bytes()
    hlen = int.from_bytes(raw[:8], "little")
    header = json.loads(raw[8 : 8 + hlen])
    start, end = header["N"]["data_offsets"]
    assert header["N"]["dtype"] == "F64" and end - start == values.size * 8
    data = bytearray(raw[8 + hlen :])
    data[start:end] = values.astype("<f8").tobytes()
    path.write_bytes(raw[: 8 + hlen] + bytes(data))


def test_at_init_it_is_the_linear_model(tmp_path):
    b = koopbridge.BilinearModel.init(nx=2, nu=1, hidden=[16, 16], n_mult=4, seed=3)
    lin = koopbridge.KoopmanModel.init(nx=2, nu=1, hidden=[16, 16], n_mult=4, seed=3)
    b.save(str(tmp_path))
    b = koopbridge.BilinearModel.load(str(tmp_path))
    np.testing.assert_array_equal(b.A, lin.A)
    np.testing.assert_array_equal(b.B, lin.B)
    assert len(b.N) == 1 and not b.N[0].any()
    u = np.linspace(-1, 1, 6).reshape(6, 1)
    np.testing.assert_allclose(b.predict([0.3, -0.2], u), lin.predict([0.3, -0.2], u), atol=1e-12)
    with pytest.raises(koopbridge.KoopbridgeError):
        koopbridge.KoopmanModel.load(str(tmp_path))


def test_predict_is_the_bilinear_rollout(tmp_path):
    b = koopbridge.BilinearModel.init(nx=2, nu=1, hidden=[16, 16], n_mult=4, seed=5)
    lin = koopbridge.KoopmanModel.init(nx=2, nu=1, hidden=[16, 16], n_mult=4, seed=5)
    n = b.latent_dim
    b.save(str(tmp_path))
    nmat = np.random.default_rng(0).normal(scale=0.1, size=(1, n, n))
    _set_n(tmp_path, nmat)
    b = koopbridge.BilinearModel.load(str(tmp_path))
    np.testing.assert_array_equal(b.N[0], nmat[0])
    x0 = np.array([0.5, -1.0])
    u = np.random.default_rng(1).uniform(-2, 2, size=(8, 1))
    z = lin.encode(x0)
    want = []
    for k in range(len(u)):
        z = b.A @ z + b.B @ u[k] + u[k, 0] * (nmat[0] @ z)
        want.append(z[:2])
    np.testing.assert_allclose(b.predict(x0, u), np.array(want), rtol=1e-10, atol=1e-12)
    assert b.metadata is None or isinstance(b.metadata, dict)
    nmat[0, 0, 0] = np.nan
    _set_n(tmp_path, nmat)
    with pytest.raises(ValueError, match="non-finite"):
        koopbridge.BilinearModel.load(str(tmp_path))
