"""The UR3 in a Rerun recording: its URDF meshes, placed on the board and moved along a trajectory.

The URDF comes from the example-robot-data wheel. Its mesh references use ROS `package://`
URIs that Rerun cannot resolve outside a ROS workspace, so a copy with absolute paths is
logged: its COLLADA visual meshes (75,000 triangles, 3.7 MB) replaced by decimated GLB files
(keymps.default_plugins.rerun.meshes), without the collision meshes.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import tempfile
from functools import cache
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import unquote, urlparse

import numpy as np
from platformdirs import user_cache_dir

from keymps.errors import KeympsError

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.types import Trajectory

URDF_SUFFIX = "robots/ur_description/urdf/ur3_robot.urdf"
PACKAGE_PREFIX = "package://example-robot-data/"
ROBOT_ENTITY = "world/robot"
MOUNT_ENTITY = "world/robot/mount"
TOOL_ENTITY = "world/robot/tool"
FLANGE_FRAME = "tool0"
"""The URDF's flange frame; the tool's TCP is given in it (keymps.robot.model's convention)."""
JOINT_ENTITY = "world/robot/joint_transforms"
URDF_ROOT_FRAME = "world"
"""The URDF's root link; `world/robot/mount` connects it to the board frame (tf#/world)."""


@cache
def ur3_urdf_path() -> Path:
    """The UR3 URDF shipped by example-robot-data (the same file the robot model loads)."""
    try:
        files = metadata.distribution("example-robot-data").files or []
    except metadata.PackageNotFoundError:
        raise KeympsError(
            "the UR3 model needs the 'example-robot-data' package: pip install example-robot-data"
        ) from None
    for file in files:
        if str(file).endswith(URDF_SUFFIX):
            return Path(str(file.locate())).resolve()
    raise KeympsError(f"example-robot-data is installed but has no {URDF_SUFFIX}")


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


JointOrigins = tuple[tuple[str, tuple[float, float, float]], ...]
"""(URDF joint name, origin xyz) pairs that replace the URDF's own joint offsets."""
TOOL0_JOINT = "wrist_3_link-tool0_fixed_joint"


def arm_joint_origins(task: Task) -> JointOrigins:
    """The joint offsets keymps.robot.model's kinematic model uses for this task's arm (the UR3's
    are the URDF's own; a UR3e's differ by up to 2 cm), so the drawn tool tip is the IK's."""
    try:
        from keymps.robot.model import RobotModel

        robot = RobotModel.from_task(task)
        model = robot.model
        origins = []
        for name in robot.joint_names:
            placement = model.jointPlacements[model.getJointId(name)]
            if name == robot.joint_names[0]:  # the base placement is folded into joint 1
                placement = robot.base_in_board.inverse() * placement
            origins.append((name, _xyz(placement.translation)))
        flange = model.frames[model.getFrameId("flange")].placement.translation
        origins.append((TOOL0_JOINT, _xyz(flange)))
        return tuple(origins)
    except (ImportError, AttributeError, KeympsError, IndexError):
        return ()  # draw the URDF as it is


def _xyz(values: Any) -> tuple[float, float, float]:
    x, y, z = (round(float(v), 9) for v in values)
    return (x, y, z)


def _set_joint_origin(urdf: str, joint: str, xyz: tuple[float, float, float]) -> str:
    pattern = re.compile(
        rf'(<joint name="{re.escape(joint)}"[^>]*>(?:(?!</joint>).)*?<origin [^>]*?xyz=")'
        r'([^"]*)(")',
        re.DOTALL,
    )
    return pattern.sub(lambda m: m.group(1) + " ".join(map(repr, xyz)) + m.group(3), urdf, 1)


@cache
def loggable_urdf(origins: JointOrigins = ()) -> Path:
    """A copy of the UR3 URDF with absolute mesh paths, its visual meshes decimated to small
    GLB files, no collision geometry, and the given joint offsets."""
    source = ur3_urdf_path()
    share = source.parents[3]  # .../share/example-robot-data/robots/ur_description/urdf
    text = source.read_text(encoding="utf-8")
    text = text.replace(PACKAGE_PREFIX, share.as_uri() + "/")
    text = re.sub(r"<collision>.*?</collision>", "", text, flags=re.DOTALL)
    text = re.sub(
        r'(<mesh filename=")([^"]+)(")',
        lambda match: match.group(1) + _loggable_mesh(match.group(2)) + match.group(3),
        text,
    )
    for joint, xyz in origins:
        text = _set_joint_origin(text, joint, xyz)
    return _cache_file(f"ur3-{_digest(text)}.urdf", text)


def mount_transform(task: Task) -> tuple[list[float], list[float]]:
    """(translation, xyzw quaternion) of the robot base in the board frame, from robot.base."""
    x, y, z, yaw_deg = task.robot.base
    half = math.radians(yaw_deg) / 2.0
    return [x, y, z], [0.0, 0.0, math.sin(half), math.cos(half)]


def log_robot_model(rec: Any, task: Task) -> Path:
    """The meshes (static) and the fixed placement of the robot base on the board; returns
    the URDF logged (log_robot_motion moves its joints)."""
    import rerun as rr

    urdf = loggable_urdf(arm_joint_origins(task))
    rec.log_file_from_path(urdf, entity_path_prefix=ROBOT_ENTITY, static=True)
    translation, quaternion = mount_transform(task)
    rec.log(
        MOUNT_ENTITY,
        rr.Transform3D(
            translation=translation,
            quaternion=rr.Quaternion(xyzw=quaternion),
            parent_frame="tf#/world",
            child_frame=URDF_ROOT_FRAME,
        ),
        static=True,
    )
    log_tool(rec, task)
    return urdf


def tool_tcp(task: Task) -> tuple[float, float, float] | None:
    """The task's tool tip in the flange frame (keymps.robot.model), or None without a known tool."""
    try:
        from keymps.robot.model import tool_from_task

        return tool_from_task(task).tcp
    except (ImportError, KeympsError):
        return None


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


def log_tool(rec: Any, task: Task) -> None:
    """The tool as a capsule from the flange to its tip, riding on the flange frame."""
    import rerun as rr

    from keymps.planning.redaction import redact_text as redact

    tcp = tool_tcp(task)
    if tcp is None:
        return
    offset = np.array(tcp, dtype=float)
    length = float(np.linalg.norm(offset))
    if length < 1e-6:
        return
    rec.log(
        TOOL_ENTITY,
        rr.CoordinateFrame(FLANGE_FRAME),
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
            f"the trajectory has {len(trajectory_joint_names)} joints but the UR3 URDF has "
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
