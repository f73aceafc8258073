"""The robot of a MuJoCo simulator in 3D: its model's visual geometry logged once, then posed from
each state by forward kinematics (the Go2, the G1, the Franka Panda, Gymnasium's MuJoCo envs)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import rerun as rr

__all__ = ["RobotPoser", "robot_for"]

# MuJoCo's visual geom groups (0-2); collision-only geoms (group 3 and up) are not drawn.
VISUAL_GROUPS = 3
# The reference ghost stands this far beside the robot (y, metres), drawn translucent.
GHOST_OFFSET = np.array([0.0, 0.8, 0.0])


class RobotPoser:
    """A compiled ``MjModel`` and how a simulator's state sets its ``qpos``."""

    def __init__(self, model: Any, qpos_of: Callable[[np.ndarray], np.ndarray | None]) -> None:
        import mujoco

        self._mj = mujoco
        self.model = model
        self.data = mujoco.MjData(model)
        self.qpos_of = qpos_of
        self.geoms = [g for g in range(model.ngeom) if model.geom_group[g] < VISUAL_GROUPS and model.geom_rgba[g, 3] > 0]

    def log_geometry(self, rec: rr.RecordingStream, root: str, ghost: bool = False) -> None:
        """Each visual geom under ``root/geom{i}`` (static), in its own frame."""
        m, t = self.model, self._mj.mjtGeom
        for g in self.geoms:
            rgba = np.array(m.geom_rgba[g], dtype=np.float32)
            if ghost:
                rgba = np.array([0.3, 0.7, 1.0, 0.35], dtype=np.float32)
            color = (rgba * 255).astype(np.uint8)
            size, kind, path = m.geom_size[g], m.geom_type[g], f"{root}/geom{g}"
            if kind == t.mjGEOM_MESH:
                mid = int(m.geom_dataid[g])
                v0, nv = int(m.mesh_vertadr[mid]), int(m.mesh_vertnum[mid])
                f0, nf = int(m.mesh_faceadr[mid]), int(m.mesh_facenum[mid])
                rec.log(
                    path,
                    rr.Mesh3D(vertex_positions=m.mesh_vert[v0 : v0 + nv], triangle_indices=m.mesh_face[f0 : f0 + nf], albedo_factor=color),
                    static=True,
                )
            elif kind == t.mjGEOM_BOX:
                rec.log(path, rr.Boxes3D(half_sizes=[size[:3]], colors=[color], fill_mode="solid"), static=True)
            elif kind == t.mjGEOM_SPHERE:
                rec.log(path, rr.Ellipsoids3D(half_sizes=[[size[0]] * 3], colors=[color], fill_mode="solid"), static=True)
            elif kind == t.mjGEOM_ELLIPSOID:
                rec.log(path, rr.Ellipsoids3D(half_sizes=[size[:3]], colors=[color], fill_mode="solid"), static=True)
            elif kind == t.mjGEOM_CAPSULE:
                # Rerun's capsule runs from its origin along +z: start it half a length down.
                rec.log(
                    path,
                    rr.Capsules3D(lengths=[2 * size[1]], radii=[size[0]], translations=[[0, 0, -size[1]]], colors=[color]),
                    static=True,
                )
            elif kind == t.mjGEOM_CYLINDER:
                rec.log(path, rr.Cylinders3D(lengths=[2 * size[1]], radii=[size[0]], colors=[color], fill_mode="solid"), static=True)

    def pose(self, x: np.ndarray, offset: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        """Every drawn geom's world position (n, 3) and rotation (n, 9) for state ``x``; None when
        the state cannot be posed (wrong length, non-finite)."""
        qpos = self.qpos_of(x)
        if qpos is None or not np.all(np.isfinite(qpos)):
            return None
        d = self.data
        d.qpos[:] = qpos
        self._mj.mj_kinematics(self.model, d)
        pos = np.array(d.geom_xpos[self.geoms])
        if offset is not None:
            pos += offset
        return pos, np.array(d.geom_xmat[self.geoms])

    def log_poses(self, rec: rr.RecordingStream, root: str, index: list[rr.TimeColumn], poses: list[tuple[np.ndarray, np.ndarray]]) -> None:
        """Several poses at once, at the times ``index`` (one per pose): one column per geom, tens
        of times cheaper than a log call per geom and step."""
        if not poses:
            return
        pos = np.stack([p for p, _ in poses])
        mat = np.stack([m for _, m in poses])
        for j, g in enumerate(self.geoms):
            rec.send_columns(
                f"{root}/geom{g}",
                indexes=index,
                columns=rr.Transform3D.columns(translation=pos[:, j], mat3x3=mat[:, j].reshape(-1, 3, 3)),
            )


def _legged(model: Any, names: list[str], base_qpos: int) -> Callable[[np.ndarray], np.ndarray | None]:
    """``qpos`` of a floating-base robot from its legged state (``legged_state_names``: the base
    quaternion first, the ``{joint}_q`` angles, the base height last); base x = y = 0, joints
    outside the state at the model's default."""
    import mujoco

    joints = [s.removesuffix("_q") for s in names if s.endswith("_q")]
    by_name = {(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or "").split("/")[-1].removesuffix("_joint"): j for j in range(model.njnt)}
    adr = [int(model.jnt_qposadr[by_name[j]]) for j in joints]
    first = names.index(f"{joints[0]}_q")
    default = np.array(model.key_qpos[0] if model.nkey else model.qpos0, dtype=np.float64)

    def qpos_of(x: np.ndarray) -> np.ndarray | None:
        if len(x) != len(names):
            return None
        q = default.copy()
        quat = x[0:4] / max(float(np.linalg.norm(x[0:4])), 1e-12)
        q[base_qpos : base_qpos + 3] = [0.0, 0.0, x[-1]]
        q[base_qpos + 3 : base_qpos + 7] = quat
        q[adr] = x[first : first + len(joints)]
        return q

    return qpos_of


def _indexed(model: Any, names: list[str], joint_names: list[str]) -> Callable[[np.ndarray], np.ndarray | None]:
    """``qpos`` where the state holds each of ``joint_names``' angles under a name of ``names``
    (the rest at the model's default)."""
    idx = [names.index(n) for n in joint_names]
    default = np.array(model.qpos0, dtype=np.float64)

    def qpos_of(x: np.ndarray) -> np.ndarray | None:
        if len(x) != len(names):
            return None
        q = default.copy()
        q[: len(idx)] = x[idx]
        return q

    return qpos_of


def robot_for(info: dict[str, Any]) -> RobotPoser | None:
    """The 3D robot of a simulator from its ``info``, or None when it is not one the viewer
    knows how to pose (not MuJoCo, or a state that does not determine the pose)."""
    env, names = str(info.get("env", "")), list(info.get("state_names", []))
    extra = info.get("extra") if isinstance(info.get("extra"), dict) else {}
    try:
        if env == "unitree-go2":
            from ..adapters.legged.go2 import model as go2_model

            go2 = go2_model.build_go2()
            return RobotPoser(go2.model, _legged(go2.model, names, go2.layout.base_qpos))
        if env.startswith("unitree-g1"):
            from ..adapters.legged.g1 import model as g1_model

            g1 = g1_model.build_g1(held="locked" if env.endswith("-locked") else "servo")
            return RobotPoser(g1.model, _legged(g1.model, names, g1.layout.base_qpos))
        if env.startswith("franka") and all(f"q{i}" in names for i in range(1, 8)):
            from ..adapters.mujoco import model as mujoco_model

            arm = mujoco_model.build_panda()
            return RobotPoser(arm.model, _indexed(arm.model, names, [f"q{i}" for i in range(1, 8)]))
        gym = extra.get("gymnasium") if isinstance(extra, dict) else None
        if isinstance(gym, dict) and gym.get("state") == "qpos,qvel" and "mujoco" in gym:
            import gymnasium

            # Only a registered id and plain numbers as options: nothing from the network is
            # imported as a module (``module:Env`` ids) or read as a file (``xml_file``).
            env_id, kwargs = str(gym.get("env_id", "")), gym.get("make_kwargs") or {}
            if ":" in env_id or env_id not in gymnasium.registry or not isinstance(kwargs, dict):
                return None
            if any(not isinstance(v, (int, float, bool)) for v in kwargs.values()):
                return None
            model = gymnasium.make(env_id, **kwargs).unwrapped.model
            nq = int(model.nq)
            return RobotPoser(model, lambda x: np.asarray(x[:nq], dtype=np.float64) if len(x) >= nq else None)
    except Exception:  # noqa: BLE001 - a robot that cannot be built is shown as plots only
        return None
    return None
