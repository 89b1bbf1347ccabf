"""The run's arm in a Rerun recording: its URDF meshes, placed on the board and moved along a
trajectory.

The URDF is the one keymps planned with (keymps.robot.urdf_model: a UR arm's lengths set to its
DH table, every mesh path resolved inside the arm's package). Rerun cannot resolve ROS
`package://` URIs outside a ROS workspace, so that copy, with absolute file URIs, is logged: its
COLLADA visual meshes (the UR3's: 75,000 triangles, 3.7 MB) replaced by decimated GLB files
(keymps.default_plugins.rerun.meshes), without the collision meshes.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import tempfile
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import unquote, urlparse

import numpy as np
from platformdirs import user_cache_dir

from keymps.errors import KeympsError

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.robot.model import RobotModel
    from keymps.types import Trajectory

ROBOT_ENTITY = "world/robot"
MOUNT_ENTITY = "world/robot/mount"
TOOL_ENTITY = "world/robot/tool"
JOINT_ENTITY = "world/robot/joint_transforms"


def ur3_urdf_path() -> Path:
    """The UR3 URDF shipped by example-robot-data (its meshes are the UR3's)."""
    from keymps.robot.description import ur_urdf_path

    return ur_urdf_path("ur3")


def _cache_folders() -> tuple[Path, Path]:
    """Where derived robot files go: the user cache folder, else the temp folder."""
    return Path(user_cache_dir("keymps")) / "urdf", Path(tempfile.gettempdir())


def _cache_file(name: str, content: str | bytes) -> Path:
    """Write a file once to the user cache folder (else the temp folder); return its path."""
    for folder in _cache_folders():
        target = folder / name
        try:
            folder.mkdir(parents=True, exist_ok=True)
            if not target.is_file():
                partial = target.with_suffix(f".{os.getpid()}.tmp")
                if isinstance(content, str):
                    partial.write_text(content, encoding="utf-8")
                else:
                    partial.write_bytes(content)
                partial.replace(target)
            return target
        except OSError:
            continue
    raise KeympsError(f"cannot write {name} to the cache folder or the temp folder")


def _digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:12]


@cache
def light_mesh(path: Path) -> Path:
    """The COLLADA visual mesh at `path` decimated to a small GLB file (meshes.py), cached
    on disk by the source's content and the method's settings, and per process."""
    from keymps.default_plugins.rerun import meshes

    source = path.read_bytes()
    key = hashlib.sha256(
        source + repr((meshes.TOLERANCE_M, meshes.BORDER_WEIGHT, meshes.CREASE_DEG, 2)).encode()
    )
    name = f"{path.stem}-{key.hexdigest()[:12]}.glb"
    for folder in _cache_folders():
        if (folder / name).is_file():
            return folder / name
    mesh = meshes.decimate(meshes.read_collada(path))
    return _cache_file(name, meshes.glb_bytes(mesh))


def _loggable_mesh(uri: str) -> str:
    path = Path(unquote(urlparse(uri).path))
    if path.suffix.lower() != ".dae" or not path.is_file():
        return uri
    try:
        return light_mesh(path).as_uri()
    except (ValueError, KeyError, IndexError, StopIteration, SyntaxError, np.linalg.LinAlgError):
        return uri  # a COLLADA file the reader does not understand is drawn as it is


def _mesh_uri(path: str) -> str:
    """A mesh's file URI, a COLLADA visual replaced by its decimated GLB."""
    if "://" in path:
        return _loggable_mesh(path)
    return _loggable_mesh(Path(path).as_uri())


@cache
def loggable_urdf(urdf_text: str, name: str) -> Path:
    """The arm's URDF as keymps uses it, with file URIs for its meshes, its visual COLLADA
    meshes decimated to small GLB files and no collision geometry, in the cache folder."""
    text = re.sub(r"<collision>.*?</collision>", "", urdf_text, flags=re.DOTALL)
    text = re.sub(
        r'(<mesh filename=")([^"]+)(")',
        lambda match: match.group(1) + _mesh_uri(match.group(2)) + match.group(3),
        text,
    )
    return _cache_file(f"{name}-{_digest(text)}.urdf", text)


def root_link(urdf_text: str) -> str:
    """The URDF's root link (no joint's child): `world/robot/mount` places it on the board."""
    import xml.etree.ElementTree as ElementTree

    root = ElementTree.fromstring(urdf_text)
    children = {child.get("link") for child in root.iter("child")}
    links = [link.get("name", "") for link in root.iter("link")]
    return next((link for link in links if link not in children), links[0] if links else "")


def mount_transform(robot: RobotModel) -> tuple[list[float], list[float]]:
    """(translation, xyzw quaternion) of the arm's root link in the board frame (robot.base)."""
    x, y, z, yaw_deg = robot.base
    half = math.radians(yaw_deg) / 2.0
    return [x, y, z], [0.0, 0.0, math.sin(half), math.cos(half)]


def log_robot_model(rec: Any, robot: RobotModel, task: Task) -> Path:
    """The meshes (static) and the fixed placement of the arm's root on the board; returns the
    URDF logged (log_robot_motion moves its joints)."""
    import rerun as rr

    text = robot.arm_model.urdf_text
    urdf = loggable_urdf(text, re.sub(r"[^A-Za-z0-9_.-]", "_", robot.model_name))
    rec.log_file_from_path(urdf, entity_path_prefix=ROBOT_ENTITY, static=True)
    translation, quaternion = mount_transform(robot)
    rec.log(
        MOUNT_ENTITY,
        rr.Transform3D(
            translation=translation,
            quaternion=rr.Quaternion(xyzw=quaternion),
            parent_frame="tf#/world",
            child_frame=root_link(text),
        ),
        static=True,
    )
    log_tool(rec, robot, task)
    return urdf


def _z_to(direction: np.ndarray) -> list[float]:
    """xyzw quaternion turning +z onto `direction` (a unit vector)."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, direction)
    sin, cos = float(np.linalg.norm(axis)), float(np.dot(z, direction))
    if sin < 1e-9:
        return [0.0, 0.0, 0.0, 1.0] if cos > 0 else [1.0, 0.0, 0.0, 0.0]
    half = math.atan2(sin, cos) / 2.0
    axis = axis / sin * math.sin(half)
    return [float(axis[0]), float(axis[1]), float(axis[2]), math.cos(half)]


def log_tool(rec: Any, robot: RobotModel, task: Task) -> None:
    """The tool as a capsule from its mount (the arm's tip link) to its tip, riding on it."""
    import rerun as rr

    from keymps.planning.redaction import redact_text as redact

    offset = np.array(robot.tool.tcp, dtype=float)
    length = float(np.linalg.norm(offset))
    if length < 1e-6:
        return
    rec.log(
        TOOL_ENTITY,
        rr.CoordinateFrame(robot.spec.tip_link),
        rr.Capsules3D(
            lengths=[length],
            radii=[0.006],
            translations=[[0.0, 0.0, 0.0]],
            quaternions=[_z_to(offset / length)],
            colors=[[200, 200, 210, 255]],
            labels=[redact(task.robot.tool.name)],
        ),
        static=True,
    )


def urdf_joint_order(trajectory_joint_names: tuple[str, ...], urdf_joints: list[Any]) -> list[Any]:
    """The URDF joint driven by each trajectory column: by name, else in chain order."""
    moving = [joint for joint in urdf_joints if joint.joint_type in ("revolute", "continuous")]
    by_name = {joint.name: joint for joint in moving}
    if all(name in by_name for name in trajectory_joint_names):
        return [by_name[name] for name in trajectory_joint_names]
    if len(moving) != len(trajectory_joint_names):
        raise KeympsError(
            f"the trajectory has {len(trajectory_joint_names)} joints but the arm's URDF has "
            f"{len(moving)} moving joints"
        )
    return moving


def log_robot_motion(
    rec: Any, urdf: Path, trajectory: Trajectory, picked: np.ndarray, stage_index: int
) -> int:
    """One Transform3D per moving joint and kept sample, on the `time` timeline; returns samples."""
    import rerun as rr
    from rerun.urdf import UrdfTree

    tree = UrdfTree.from_file_path(urdf)
    joints = urdf_joint_order(trajectory.joint_names, tree.joints())
    times = np.asarray(trajectory.t, dtype=float)[picked]
    indexes = [
        rr.TimeColumn("time", duration=times),
        rr.TimeColumn("stage", sequence=np.full(len(picked), stage_index)),
    ]
    for column, joint in enumerate(joints):
        values = np.asarray(trajectory.q, dtype=float)[picked, column]
        rec.send_columns(
            f"{JOINT_ENTITY}/{joint.name}",
            indexes=indexes,
            columns=joint.compute_transform_columns(values.tolist(), clamp=False),
        )
    return len(picked)
