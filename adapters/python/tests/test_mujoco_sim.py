"""The MuJoCo Franka Panda as a Simulator: check_adapter in both state layouts, the end-effector
position against Franka's published kinematics (DH parameters), SPEC's seeded reset, velocity
tracking with and without gravity compensation, command clipping, and what info reports."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from koopbridge.adapters.mujoco.model import HOME, PandaOptions  # noqa: E402
from koopbridge.adapters.mujoco.sim import FrankaSimulator  # noqa: E402
from koopbridge.testing import check_adapter  # noqa: E402

# Franka Emika's published kinematics (Craig's modified DH: a, d, alpha per joint; the
# flange is d = 0.107 in Franka's documentation, 0.1065 in robosuite's model).
FRANKA_DH = [(0, 0.333, 0), (0, 0, -np.pi / 2), (0, 0.316, np.pi / 2), (0.0825, 0, np.pi / 2), (-0.0825, 0.384, -np.pi / 2), (0, 0, np.pi / 2), (0.088, 0, np.pi / 2)]
FLANGE = 0.1065


def dh_position(q: np.ndarray) -> np.ndarray:
    """The flange position by Franka's DH table, independent of MuJoCo."""

    def link(a, d, alpha, theta):
        ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
        return np.array([[ct, -st, 0, a], [st * ca, ct * ca, -sa, -d * sa], [st * sa, ct * sa, ca, d * ca], [0, 0, 0, 1]])

    m = np.eye(4)
    for (a, d, alpha), th in zip(FRANKA_DH, q, strict=False):
        m = m @ link(a, d, alpha, th)
    return (m @ link(0, FLANGE, 0, 0))[:3, 3]


@pytest.fixture(scope="module")
def sim():
    return FrankaSimulator()


def test_check_adapter_17d(sim):
    info = check_adapter(sim, steps=6)
    assert info.nx == 17 and info.nu == 7 and info.kind == "mujoco"


def test_check_adapter_14d():
    info = check_adapter(FrankaSimulator(state="q,qd"), steps=4, zenoh=False)
    assert info.state_names == [f"q{i}" for i in range(1, 8)] + [f"qd{i}" for i in range(1, 8)]


def test_info_has_names_units_bounds_dt_and_version(sim):
    info = sim.info()
    assert info.dt == pytest.approx(0.02) and info.u_min == [-0.3] * 7 and info.u_max == [0.3] * 7
    assert info.state_names[:4] == ["ee_x", "ee_y", "ee_z", "q1"] and info.state_names[-1] == "qd7"
    mj = info.extra["mujoco"]
    assert mj["version"] == mujoco.__version__ and info.version == f"MuJoCo {mujoco.__version__}"
    assert mj["units"]["state"] == ["m"] * 3 + ["rad"] * 7 + ["rad/s"] * 7 and mj["units"]["input"] == ["rad/s"] * 7
    assert mj["substeps"] == 10 and mj["timestep"] == 0.002
    # Joint limits as the model has them, and robosuite's motor limits as the servo force limits.
    assert mj["state_bounds"]["low"][3] == pytest.approx(-2.8973) and mj["state_bounds"]["high"][6] == pytest.approx(-0.0698)
    assert mj["actuation"]["force_range"] == [[-80.0, 80.0]] * 5 + [[-12.0, 12.0]] * 2


def test_end_effector_is_franka_kinematics(sim):
    rng = np.random.default_rng(4)
    for _ in range(25):
        q = rng.uniform(sim.q_lo, sim.q_hi)
        np.testing.assert_allclose(sim.ee_position(q), dh_position(q), atol=1e-12)
    # The state's ee part is MuJoCo's site position of the same q after stepping.
    x = sim.reset(seed=9)
    for _ in range(3):
        x = sim.step(rng.uniform(-0.3, 0.3, 7))
    np.testing.assert_allclose(x[:3], dh_position(x[3:10]), atol=1e-12)
    np.testing.assert_array_equal(x[:3], sim.data.site_xpos[sim.arm.ee_site])
    # Home is at the centre of SPEC's figure-8 (x = 0.3, z = 0.59) to within a centimetre.
    np.testing.assert_allclose(dh_position(np.array(HOME)), [0.3, 0.0, 0.59], atol=0.01)


def test_seeded_reset_is_specs_draw(sim):
    for seed in (0, 1, 42):
        x = sim.reset(seed=seed)
        want = np.clip(np.array(HOME) + np.random.default_rng(seed).uniform(-0.2, 0.2, 7), sim.q_lo, sim.q_hi)
        np.testing.assert_array_equal(x[3:10], want)
        np.testing.assert_array_equal(x[10:], np.zeros(7))
    np.testing.assert_array_equal(sim.reset()[3:10], HOME)


def tracking_error(sim: FrankaSimulator, windows: int = 30, T: int = 15) -> float:
    """Mean |qd − command| at the end of each step under SPEC's data commands U(±0.12)."""
    rng = np.random.default_rng(0)
    errs = []
    for w in range(windows):
        sim.reset(seed=w)
        for _ in range(T):
            u = rng.uniform(-0.12, 0.12, 7)
            errs.append(np.abs(sim.step(u)[10:] - u).mean())
    return float(np.mean(errs))


def test_velocity_tracking_with_and_without_gravity_compensation(sim):
    with_gc = tracking_error(sim)
    without = tracking_error(FrankaSimulator(options=PandaOptions(gravcomp=False)))
    print(f"mean velocity-tracking error: {with_gc:.4f} rad/s with gravity compensation, {without:.4f} without")
    assert with_gc < 0.004
    assert without > 1.5 * with_gc


def test_commands_are_clipped(sim):
    sim.reset()
    for _ in range(10):
        x = sim.step(np.full(7, 5.0))
    # Joint 1 carries the whole arm and joint 7 nearly nothing: both settle at the clipped 0.3.
    assert np.all(np.abs(x[10:] - 0.3) < 0.02), x[10:]
