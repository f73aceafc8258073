"""The Franka Panda MuJoCo model for koopbridge: robosuite's MJCF (found as a folder of files,
robosuite is never imported), edited with ``mujoco.MjSpec`` to joint-velocity servos with the
arm's force limits, gravity compensation and an end-effector site."""

from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass
from typing import Any

from ..._native import KoopbridgeError

__all__ = [
    "HOME",
    "JOINTS",
    "ModelError",
    "PandaModel",
    "PandaOptions",
    "build_panda",
    "robosuite_panda_xml",
]

#: The seven arm joints, base to flange (the names in robosuite's and Menagerie's Panda).
JOINTS = tuple(f"joint{i}" for i in range(1, 8))
#: SPEC's home configuration (rad).
HOME = (0.0, -0.78, 0.0, -2.35, 0.0, 1.57, 0.78)
#: What robosuite's ``RobotModel`` sets on every arm joint when it loads a robot (robosuite
#: 1.5.2, ``models/robots/robot_model.py``): armature 5/(i+1), frictionloss 0.1.
ROBOSUITE_ARMATURE = tuple(5.0 / (i + 1) for i in range(7))
ROBOSUITE_FRICTIONLOSS = 0.1
#: The pinned robosuite release whose Panda is the default model (see adapters/mujoco/README.md).
ROBOSUITE_VERSION = "1.5.2"


class ModelError(KoopbridgeError):
    """A problem with the MuJoCo model; the message names the file and the cause."""


def robosuite_panda_xml() -> str:
    """The path of robosuite's ``models/assets/robots/panda/robot.xml`` (robosuite installed with
    ``pip install --no-deps``; located with ``importlib.util.find_spec``, not imported)."""
    spec = importlib.util.find_spec("robosuite")
    if spec is None or not spec.submodule_search_locations:
        raise ModelError(
            f"the default Franka Panda model comes from robosuite=={ROBOSUITE_VERSION}, which is not installed "
            f"(scripts/setup-python.sh installs it; by hand: pip install --no-deps robosuite=={ROBOSUITE_VERSION}), "
            "or pass --model FILE"
        )
    return os.path.join(list(spec.submodule_search_locations)[0], "models", "assets", "robots", "panda", "robot.xml")


@dataclass
class PandaOptions:
    """How the arm is actuated and simulated.

    ``kv``: velocity-servo gain (N·m·s/rad); ``u_limit``: commands are clipped to ±u_limit
    rad/s; ``gravcomp``: gravity compensation on every body, applied through the actuators;
    ``timestep`` × ``substeps`` = one ``step`` (``dt``); ``ee_body``: the body whose origin is
    the end effector (robosuite's flange mount ``right_hand``); ``armature``/``frictionloss``:
    joint settings applied on top of the file's (default: robosuite's, as its loader does);
    ``force_limit``: per-joint force limits (default: the file's motor ``ctrlrange``).
    """

    kv: float = 1000.0
    u_limit: float = 0.3
    gravcomp: bool = True
    timestep: float = 0.002
    substeps: int = 10
    ee_body: str = "right_hand"
    armature: tuple[float, ...] | None = ROBOSUITE_ARMATURE
    frictionloss: float | None = ROBOSUITE_FRICTIONLOSS
    force_limit: tuple[float, ...] | None = None

    @property
    def dt(self) -> float:
        """Seconds per macro step."""
        return self.timestep * self.substeps


@dataclass
class PandaModel:
    """A compiled arm: the ``MjModel`` and what koopbridge needs to know about it."""

    model: Any
    path: str
    options: PandaOptions
    qpos_adr: list[int]
    dof_adr: list[int]
    joint_range: list[tuple[float, float]]
    force_range: list[tuple[float, float]]
    ee_site: int


def _load_spec(path: str) -> Any:
    import mujoco

    if not os.path.isfile(path):
        raise ModelError(f"MuJoCo model '{path}': file not found")
    try:
        return mujoco.MjSpec.from_file(path)
    except ValueError as e:
        raise ModelError(f"MuJoCo model '{path}': cannot parse it ({str(e).strip()})") from e


def build_panda(path: str | None = None, options: PandaOptions | None = None) -> PandaModel:
    """Loads the MJCF at ``path`` (default: robosuite's Panda), replaces its actuators by one
    velocity servo per arm joint (``kv``, control range ±``u_limit``, force range = the arm's
    limits), turns on gravity compensation, adds the site ``ee`` at ``ee_body``'s origin, sets
    the integrator (implicitfast) and timestep, and compiles. Errors name the file."""
    import mujoco

    opts = options or PandaOptions()
    path = os.path.abspath(path or robosuite_panda_xml())
    spec = _load_spec(path)
    joints = {j.name: j for j in spec.joints}
    missing = [n for n in JOINTS if n not in joints]
    if missing:
        raise ModelError(f"MuJoCo model '{path}': no joint {', '.join(missing)} (a 7-joint arm with joints joint1..joint7 is expected)")
    limits: dict[str, tuple[float, float]] = {}
    for act in list(spec.actuators):
        if act.target in JOINTS:
            ranged = float(act.forcerange[0]) < float(act.forcerange[1])
            if act.forcelimited == mujoco.mjtLimited.mjLIMITED_TRUE or (act.forcelimited == mujoco.mjtLimited.mjLIMITED_AUTO and ranged):
                limits[act.target] = (float(act.forcerange[0]), float(act.forcerange[1]))
            elif act.ctrllimited != mujoco.mjtLimited.mjLIMITED_FALSE and act.gainprm[0] != 0:
                g = float(act.gainprm[0])
                lo, hi = sorted((float(act.ctrlrange[0]) * g, float(act.ctrlrange[1]) * g))
                limits[act.target] = (lo, hi)
        spec.delete(act)
    if opts.force_limit is not None:
        if len(opts.force_limit) != 7:
            raise ModelError(f"force_limit has {len(opts.force_limit)} values, the arm has 7 joints")
        limits = {n: (-abs(f), abs(f)) for n, f in zip(JOINTS, opts.force_limit, strict=False)}
    no_limit = [n for n in JOINTS if n not in limits]
    if no_limit:
        raise ModelError(f"MuJoCo model '{path}': no force limit for {', '.join(no_limit)} (no limited actuator on it; pass force limits)")
    for i, name in enumerate(JOINTS):
        j = joints[name]
        if opts.armature is not None:
            j.armature = float(opts.armature[i])
        if opts.frictionloss is not None:
            j.frictionloss = float(opts.frictionloss)
        act = spec.add_actuator(name=f"vel_{name}", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_velocity(kv=float(opts.kv))
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.ctrlrange = [-opts.u_limit, opts.u_limit]
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = list(limits[name])
        if opts.gravcomp:
            j.actgravcomp = 1
    if opts.gravcomp:
        for b in spec.bodies:
            b.gravcomp = 1.0
    try:
        ee = spec.body(opts.ee_body)
    except Exception:
        ee = None
    if ee is None:
        raise ModelError(f"MuJoCo model '{path}': no body '{opts.ee_body}' for the end effector")
    ee.add_site(name="koopbridge_ee", pos=[0.0, 0.0, 0.0], size=[0.01, 0.01, 0.01])
    spec.option.timestep = opts.timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    try:
        m = spec.compile()
    except ValueError as e:
        raise ModelError(f"MuJoCo model '{path}': cannot compile it ({str(e).strip()})") from e
    jids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in JOINTS]
    return PandaModel(
        model=m,
        path=path,
        options=opts,
        qpos_adr=[int(m.jnt_qposadr[j]) for j in jids],
        dof_adr=[int(m.jnt_dofadr[j]) for j in jids],
        joint_range=[(float(m.jnt_range[j][0]), float(m.jnt_range[j][1])) for j in jids],
        force_range=[limits[n] for n in JOINTS],
        ee_site=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "koopbridge_ee"),
    )
