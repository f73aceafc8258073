"""The uniform collect policy's initial-state box (PROTOCOL.md, "Collect"): every window resets
to x0 ~ U(x0_low, x0_high) drawn from its own generator after the reset seed, on a real FMU."""

import numpy as np
import pytest

from koopbridge import InvalidInput
from koopbridge.adapters.fmu.sim import FmuSimulator
from koopbridge.collect import collect_windows, policy_from_json, window_rng


def test_windows_start_in_the_box_drawn_from_their_own_stream(damped_fmu):
    sim = FmuSimulator(str(damped_fmu), ["u"], ["theta", "omega"], dt=0.02, initial=["theta0", "omega0"], x0_low=[-1, -1], x0_high=[1, 1])
    box = {"kind": "uniform", "low": -0.5, "high": 0.5, "x0_low": [0.1, -0.2], "x0_high": [0.3, 0.0]}
    p = policy_from_json(box)
    assert p.to_json() == {**box, "low": [-0.5], "high": [0.5]}
    w = collect_windows(sim, p, 7, 4, 3, start=2)
    for i in range(4):
        r = window_rng(7, 2 + i)
        r.integers(0, 2**63)
        x0 = r.uniform([0.1, -0.2], [0.3, 0.0])
        assert np.array_equal(w.x[i, 0], x0)
        assert np.array_equal(w.u[i], r.uniform(-0.5, 0.5, size=(3, 1)))
    again = collect_windows(sim, p, 7, 4, 3, start=2)
    assert np.array_equal(again.x, w.x)
    with pytest.raises(InvalidInput, match="2 values"):
        collect_windows(sim, policy_from_json({"kind": "uniform", "x0_low": [0.1], "x0_high": [0.3]}), 7, 1, 3)
    with pytest.raises(InvalidInput, match="go together"):
        collect_windows(sim, policy_from_json({"kind": "uniform", "x0_low": [0.1, 0.0]}), 7, 1, 3)
