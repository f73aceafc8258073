"""The Kinova Gen3 (7 DoF) for Drake, offline: robosuite's MJCF of the arm, cleaned for Drake's
MJCF parser and cached, plus its joint limits and a builder of the ``MultibodyPlant``.

The MJCF is ``models/assets/robots/kinova3/robot.xml`` of the ``robosuite`` package (version
1.5.2, MIT; installed with ``pip install --no-deps`` and used only as files: robosuite is never
imported). Its inertials and joint origins are Kinova's ``kortex_description``. Drake's MJCF
parser reads only ``.obj`` meshes, so the cleaned copy drops the visual-only mesh geoms,
converts the collision meshes (binary or ASCII STL) to ``.obj`` and gives zero-mass bodies a
tiny mass. The copy lives in a cache folder keyed by the content hash (``$KOOPBRIDGE_CACHE``,
else ``~/.cache/koopbridge``), written to a temporary folder and renamed, never in the repository.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import struct
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..._native import KoopbridgeError

__all__ = [
    "CONTINUOUS",
    "EFFORT_LIMITS",
    "JOINT_NAMES",
    "POSITION_LIMITS",
    "VELOCITY_LIMITS",
    "Gen3",
    "ModelError",
    "build_gen3",
    "cleaned_mjcf",
    "robosuite_mjcf",
]

#: The arm's joints in order (names of robosuite's MJCF).
JOINT_NAMES = [f"Actuator{i}" for i in range(1, 8)]
#: Joints without position limits (continuous; random goals use ±π for them).
CONTINUOUS = np.array([True, False, True, False, True, False, True])
#: Position limits [rad] (kortex_description ``gen3`` 7-DoF: joints 2, 4, 6; others continuous).
POSITION_LIMITS = np.array([np.inf, 2.41, np.inf, 2.66, np.inf, 2.23, np.inf])
#: Velocity limits [rad/s] (kortex_description: 1.3963 for joints 1-4, 1.2218 for joints 5-7).
VELOCITY_LIMITS = np.array([1.3963] * 4 + [1.2218] * 3)
#: Effort limits [N·m] (kortex_description: 39 for joints 1-4, 9 for joints 5-7).
EFFORT_LIMITS = np.array([39.0] * 4 + [9.0] * 3)
#: Bodies of the arm, base to flange, as named in the MJCF.
LINK_NAMES = [
    "shoulder_link",
    "HalfArm1_Link",
    "HalfArm2_Link",
    "forearm_link",
    "SphericalWrist1_Link",
    "SphericalWrist2_Link",
    "Bracelet_Link",
    "right_hand",
]
#: Version of the cleaning below (part of the cache key).
_CLEANER = "3"
_TINY_MASS = "1e-6"
_TINY_INERTIA = "1e-9 1e-9 1e-9"


class ModelError(KoopbridgeError):
    """The Gen3 model cannot be found, read or built; the message names the file and the cause."""


def robosuite_mjcf() -> Path:
    """The path of robosuite's ``kinova3/robot.xml`` (found without importing robosuite)."""
    try:
        spec = importlib.util.find_spec("robosuite")
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        raise ModelError(
            "the Kinova Gen3 model comes from the robosuite package (files only): "
            "pip install --no-deps robosuite==1.5.2"
        )
    for root in spec.submodule_search_locations:
        p = Path(root) / "models" / "assets" / "robots" / "kinova3" / "robot.xml"
        if p.is_file():
            return p
    raise ModelError(f"robosuite at {list(spec.submodule_search_locations)} has no models/assets/robots/kinova3/robot.xml")


def read_stl(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``[n, 3]`` and triangles ``[m, 3]`` (indices) of a binary or ASCII STL file,
    with duplicate vertices merged."""
    data = path.read_bytes()
    tris: np.ndarray
    if len(data) >= 84 and len(data) == 84 + 50 * struct.unpack_from("<I", data, 80)[0]:
        n = struct.unpack_from("<I", data, 80)[0]
        rec = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]), count=n, offset=84)
        tris = rec["v"].astype(float)
    else:
        words = data.decode("ascii", "replace").split()
        vs = [[float(words[i + 1]), float(words[i + 2]), float(words[i + 3])] for i, w in enumerate(words) if w == "vertex"]
        if not vs or len(vs) % 3:
            raise ModelError(f"{path}: not a readable STL file")
        tris = np.asarray(vs, float).reshape(-1, 3, 3)
    if tris.size == 0 or not np.all(np.isfinite(tris)):
        raise ModelError(f"{path}: STL without finite triangles")
    verts, inv = np.unique(np.round(tris.reshape(-1, 3), 9), axis=0, return_inverse=True)
    return verts, inv.reshape(-1, 3)


def _write_obj(path: Path, verts: np.ndarray, faces: np.ndarray) -> None:
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in verts]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces if len({a, b, c}) == 3]
    path.write_text("\n".join(lines) + "\n")


def _clean(src: Path, out_dir: Path, collision: bool) -> str:
    """The cleaned MJCF text; writes the collision meshes as ``.obj`` into ``out_dir``."""
    try:
        tree = ET.parse(src)
    except (ET.ParseError, OSError) as e:
        raise ModelError(f"{src}: cannot read the MJCF ({e})") from e
    root = tree.getroot()
    assets = {m.get("name") or Path(m.get("file", "")).stem: m for m in root.iter("mesh")}
    used: set[str] = set()
    for parent in list(root.iter()):
        for child in list(parent):
            if child.tag in ("camera", "site"):
                parent.remove(child)  # Drake's parser ignores these (with a warning)
            elif child.tag == "geom" and child.get("type") == "mesh":
                visual_only = child.get("contype") == "0" and child.get("conaffinity") == "0"
                if visual_only or not collision:
                    parent.remove(child)
                else:
                    used.add(child.get("mesh", ""))
                    # Drake has no MJCF collision groups (it warns); its own filters apply.
                    child.attrib.pop("contype", None)
                    child.attrib.pop("conaffinity", None)
    for asset in root.iter("asset"):
        for m in list(asset):
            if m.tag != "mesh":
                continue
            name = m.get("name") or Path(m.get("file", "")).stem
            if name not in used:
                asset.remove(m)
                continue
            verts, faces = read_stl(src.parent / m.get("file", ""))
            obj = out_dir / f"{name}.obj"
            _write_obj(obj, verts, faces)
            m.set("file", str(obj))
            m.set("name", name)
    missing = used - set(assets)
    if missing:
        raise ModelError(f"{src}: mesh geoms refer to unknown meshes {sorted(missing)}")
    for body in root.iter("body"):
        inertial = body.find("inertial")
        if inertial is None:
            inertial = ET.SubElement(body, "inertial", pos="0 0 0")
            inertial.set("mass", "0")
        if float(inertial.get("mass", "0")) <= 0.0:
            inertial.set("mass", _TINY_MASS)
            inertial.set("diaginertia", _TINY_INERTIA)
            inertial.attrib.pop("fullinertia", None)
    return ET.tostring(root, encoding="unicode")


def _cache_root() -> Path:
    return Path(os.environ.get("KOOPBRIDGE_CACHE") or Path.home() / ".cache" / "koopbridge")


def cleaned_mjcf(collision: bool = True, src: Path | None = None) -> Path:
    """The Drake-readable copy of the Gen3 MJCF (with the arm's collision meshes as ``.obj`` when
    ``collision``), built once per content hash into the cache and reused."""
    src = Path(src) if src is not None else robosuite_mjcf()
    h = hashlib.sha256(src.read_bytes())
    h.update(f"{_CLEANER}:{collision}".encode())
    for m in ET.parse(src).getroot().iter("mesh"):
        f = src.parent / m.get("file", "")
        if f.is_file():
            h.update(f.read_bytes())
    final = _cache_root() / "drake" / f"gen3-{h.hexdigest()[:16]}"
    if (final / "robot.xml").is_file():
        return final / "robot.xml"
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".gen3-", dir=final.parent))
    try:
        # Mesh paths inside the text point to the final folder, where they live after the rename.
        text = _clean(src, tmp, collision).replace(str(tmp), str(final))
        (tmp / "robot.xml").write_text(text)
        try:
            os.replace(tmp, final)
        except OSError:
            if not (final / "robot.xml").is_file():  # another process won the race otherwise
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return final / "robot.xml"


@dataclass
class Gen3:
    """A built Gen3 diagram: ``plant`` (finalised), ``scene_graph``, ``diagram`` and the arm's
    ``model`` instance; ``table`` is the table box's geometry id (None without collision)."""

    diagram: Any
    plant: Any
    scene_graph: Any
    model: Any
    builder_time_step: float
    table: Any = None

    def link_bodies(self) -> list[Any]:
        """The arm's bodies, base to flange (``LINK_NAMES``)."""
        return [self.plant.GetBodyByName(n, self.model) for n in LINK_NAMES]


def build_gen3(time_step: float = 0.0, collision: bool = True, table_z: float | None = 0.0, builder: Any = None, finalize_diagram: bool = True) -> Gen3:
    """The Gen3 in a ``MultibodyPlant`` (``time_step`` 0: continuous) with its ``SceneGraph``.

    With ``collision`` the arm's links carry their collision meshes (convex hulls in Drake's
    proximity queries) and, unless ``table_z`` is None, a table is a 2 m x 2 m box whose top is at
    height ``table_z`` [m] (the base sits at 0). Velocity and effort limits are set from
    kortex_description (the MJCF has none). ``builder``: add to this ``DiagramBuilder`` instead
    of a new one; ``finalize_diagram=False`` leaves building the diagram to the caller."""
    from pydrake.geometry import Box
    from pydrake.math import RigidTransform
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, CoulombFriction
    from pydrake.systems.framework import DiagramBuilder

    path = cleaned_mjcf(collision=collision)
    b = builder if builder is not None else DiagramBuilder()
    plant, sg = AddMultibodyPlantSceneGraph(b, time_step)
    try:
        models = Parser(plant).AddModels(str(path))
    except RuntimeError as e:
        raise ModelError(f"{path}: Drake's MJCF parser refused it ({e})") from e
    if len(models) != 1:
        raise ModelError(f"{path}: expected one model instance, Drake made {len(models)}")
    model = models[0]
    for name, v in zip(JOINT_NAMES, VELOCITY_LIMITS, strict=False):
        plant.GetJointByName(name, model).set_velocity_limits([-v], [v])
    for i in range(len(JOINT_NAMES)):
        act = plant.GetJointActuatorByName(f"torq_j{i + 1}", model)
        act.set_effort_limit(float(EFFORT_LIMITS[i]))
    table = None
    if collision and table_z is not None:
        table = plant.RegisterCollisionGeometry(
            plant.world_body(),
            RigidTransform([0.0, 0.0, table_z - 0.05]),
            Box(2.0, 2.0, 0.1),
            "table",
            CoulombFriction(0.5, 0.5),
        )
    plant.Finalize()
    diagram = b.Build() if finalize_diagram else None
    return Gen3(diagram=diagram, plant=plant, scene_graph=sg, model=model, builder_time_step=time_step, table=table)
