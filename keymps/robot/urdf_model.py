"""An arm's URDF made into the Pinocchio model and collision model keymps plans and checks with.

The URDF is read as text (at most MAX_URDF_BYTES) and edited before Pinocchio sees it:
continuous joints become revolute joints of two turns each way, a Universal Robots arm's
joint origins are set to its DH table, a link's meshes may be stretched, and every mesh path
is resolved to an absolute file that must lie inside the arm's package folders (links
followed): a URDF from a stranger's task reads no file outside its own folder. The joints
that are not the arm's (a gripper's) are locked at their neutral position.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import unquote, urlsplit

import numpy as np

from keymps.errors import KeympsError
from keymps.plugin.arms import DEFAULT_ACCELERATION, DEFAULT_JERK

if TYPE_CHECKING:
    from keymps.plugin.components import Arm

MAX_URDF_BYTES = 5_000_000
"""A robot's URDF is tens of kilobytes; a larger file is refused unread."""
UR_JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
UR_FLANGE_JOINTS = ("wrist_3_link-tool0_fixed_joint", "ee_fixed_joint")
"""The fixed joints that place tool0 (the flange) and ee_link d6 beyond wrist 3."""


@dataclass(frozen=True)
class ArmModel:
    """An arm as keymps uses it, its root link at the origin (RobotModel places it)."""

    spec: Arm
    model: Any
    """pinocchio.Model with the arm's joints only (in `joint_names` order)."""
    urdf: ElementTree.Element
    """The URDF as edited (below)."""
    urdf_text: str
    """The URDF as edited: absolute mesh paths, the UR lengths, the locked joints kept."""
    flange_joint: int
    flange_placement: Any
    """pinocchio.SE3 of `spec.tip_link` on its parent joint: the tool mount."""
    joint_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray
    effort: np.ndarray
    home: np.ndarray

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    @cached_property
    def collision(self) -> Any:
        """pinocchio.GeometryModel of the URDF's collision shapes (convex hulls), built on
        first use (reading an arm's meshes takes up to a second or two)."""
        from keymps.robot.collision import build_geometry, collision_shapes

        try:
            return build_geometry(self.model, collision_shapes(self.urdf))
        except (OSError, ValueError, RuntimeError) as error:
            message = f"cannot read its collision meshes: {_one_line(error)}"
            raise arm_error(self.spec, message) from None


_LOADED: dict[Any, ArmModel] = {}


def load_arm(spec: Arm) -> ArmModel:
    """The arm's models (built once per process and spec; about 50 ms for a meshed arm)."""
    try:
        key: Any = hash(spec) and spec
    except TypeError:  # an Arm that is not hashable is built every time
        key = None
    if key is not None and key in _LOADED:
        return _LOADED[key]
    arm = _build(spec)
    if key is not None:
        _LOADED[key] = arm
    return arm


def arm_error(spec: Arm, message: str) -> KeympsError:
    return KeympsError(f"robot: arm {spec.name!r} ({spec.urdf}): {message}")


def _build(spec: Arm) -> ArmModel:
    import pinocchio as pin

    root = read_urdf(spec)
    _make_continuous_revolute(root)
    if spec.dh is not None:
        _apply_ur_lengths(spec, root, spec.dh)
    _scale_meshes(root, dict(spec.mesh_scales))
    _resolve_meshes(spec, root)
    text = ElementTree.tostring(root, encoding="unicode")
    try:
        full = pin.buildModelFromXML(text)
    except (RuntimeError, ValueError) as error:
        raise arm_error(spec, f"Pinocchio cannot read the URDF: {_one_line(error)}") from None
    if not full.existFrame(spec.tip_link):
        raise arm_error(spec, f"no link {spec.tip_link!r} (the tool mount, tip_link)")
    joints = _arm_joints(spec, full)
    locked = [j for j in range(1, full.njoints) if j not in joints]
    model = pin.buildReducedModel(full, locked, pin.neutral(full))
    tip = model.frames[model.getFrameId(spec.tip_link)]
    names = tuple(model.names[j] for j in range(1, model.njoints))
    limits = _limits(spec, model)
    return ArmModel(spec, model, root, text, int(tip.parentJoint), tip.placement, names, *limits)


def read_urdf(spec: Arm) -> ElementTree.Element:
    """The URDF's XML tree (one located KeympsError for a missing, huge or broken file)."""
    path = Path(spec.urdf)
    try:
        size = path.stat().st_size
        if not path.is_file():
            raise arm_error(spec, "the URDF is not a regular file")
        if size > MAX_URDF_BYTES:
            raise arm_error(spec, f"the URDF has {size} bytes, more than {MAX_URDF_BYTES}")
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise arm_error(spec, f"cannot read the URDF: {error.strerror}") from None
    except UnicodeDecodeError:
        raise arm_error(spec, "the URDF is not UTF-8 text") from None
    try:
        root = ElementTree.fromstring(text)
    except ElementTree.ParseError as error:
        raise arm_error(spec, f"the URDF is not valid XML: {error}") from None
    if root.tag != "robot":
        raise arm_error(spec, f"the URDF's root element is <{root.tag}>, not <robot>")
    return root


def _one_line(error: BaseException) -> str:
    return " ".join(str(error).split())


def _make_continuous_revolute(root: ElementTree.Element) -> None:
    """Continuous joints become revolute joints of +-2 pi (Pinocchio's continuous joints have
    two coordinates, cos and sin, which no controller sends)."""
    for joint in root.iter("joint"):
        if joint.get("type") != "continuous":
            continue
        joint.set("type", "revolute")
        limit = joint.find("limit")
        if limit is None:
            limit = ElementTree.SubElement(joint, "limit", {"effort": "0", "velocity": "0"})
        limit.set("lower", repr(-2 * math.pi))
        limit.set("upper", repr(2 * math.pi))


def _joint(spec: Arm, root: ElementTree.Element, name: str) -> ElementTree.Element:
    for joint in root.iter("joint"):
        if joint.get("name") == name:
            return joint
    raise arm_error(spec, f"a Universal Robots URDF needs the joint {name!r}; it has none")


def _xyz(joint: ElementTree.Element) -> list[float]:
    origin = joint.find("origin")
    return [
        float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()
    ]


def _set_xyz(joint: ElementTree.Element, xyz: tuple[float, float, float]) -> None:
    origin = joint.find("origin")
    if origin is None:
        origin = ElementTree.SubElement(joint, "origin", {"rpy": "0 0 0"})
    origin.set("xyz", " ".join(repr(float(v)) for v in xyz))


def _apply_ur_lengths(spec: Arm, root: ElementTree.Element, dh: tuple[float, ...]) -> None:
    """The UR URDF's joint origins set to the DH table (d1, a2, a3, d4, d5, d6): the lateral
    offsets of the shoulder and the elbow are the URDF's own, wrist 2 takes the rest of d4."""
    d1, a2, a3, d4, d5, d6 = dh
    pan, lift, elbow, wrist1, wrist2, wrist3 = (_joint(spec, root, n) for n in UR_JOINTS)
    shoulder_y, elbow_y = _xyz(lift)[1], _xyz(elbow)[1]
    _set_xyz(pan, (0.0, 0.0, d1))
    _set_xyz(elbow, (0.0, elbow_y, -a2))
    _set_xyz(wrist1, (0.0, 0.0, -a3))
    _set_xyz(wrist2, (0.0, d4 - shoulder_y - elbow_y, 0.0))
    _set_xyz(wrist3, (0.0, 0.0, d5))
    for joint in root.iter("joint"):
        if joint.get("name") in UR_FLANGE_JOINTS:
            _set_xyz(joint, (0.0, d6, 0.0))


def _scale_meshes(root: ElementTree.Element, scales: dict[str, tuple[float, float, float]]) -> None:
    for link in root.iter("link"):
        scale = scales.get(link.get("name", ""))
        if scale is None:
            continue
        for mesh in link.iter("mesh"):
            old = [float(v) for v in mesh.get("scale", "1 1 1").split()]
            mesh.set("scale", " ".join(repr(a * b) for a, b in zip(old, scale, strict=True)))


def mesh_roots(spec: Arm) -> tuple[Path, ...]:
    """Folders the arm's meshes may be read from: its package folders, else the folder
    above the URDF's (a ROS package: urdf/ beside meshes/)."""
    folders = spec.package_dirs or (Path(spec.urdf).resolve().parent.parent,)
    return tuple(Path(folder).resolve() for folder in folders)


def _resolve_meshes(spec: Arm, root: ElementTree.Element) -> None:
    """Every <mesh filename> made an absolute path to an existing file inside mesh_roots."""
    roots = mesh_roots(spec)
    for link in root.iter("link"):
        for mesh in link.iter("mesh"):
            written = mesh.get("filename", "")
            found = _find_mesh(spec, written, roots)
            inside = any(found == r or r in found.parents for r in roots)
            if not inside:
                raise arm_error(
                    spec,
                    f"link {link.get('name')!r}: mesh {written!r} is outside the arm's folders "
                    f"({', '.join(map(str, roots))}); not read",
                )
            mesh.set("filename", str(found))


def _find_mesh(spec: Arm, written: str, roots: tuple[Path, ...]) -> Path:
    """The real path (links followed) a mesh filename names."""
    parts = urlsplit(written)
    urdf_folder = Path(spec.urdf).resolve().parent
    if parts.scheme == "package":
        package, rest = parts.netloc, unquote(parts.path).lstrip("/")
        bases = [*roots, *(r.parent for r in roots), urdf_folder, *urdf_folder.parents]
        candidates = [b / package / rest for b in bases]
        candidates += [b / rest for b in bases if b.name == package]
        candidates += [root / rest for root in roots]  # the arm's own folder is its package
    elif parts.scheme in ("file", ""):
        candidates = [urdf_folder / unquote(parts.path)]  # an absolute path stays absolute
    else:
        raise arm_error(spec, f"mesh {written!r}: only package://, file:// and paths are read")
    for candidate in candidates:
        try:
            if candidate.is_file():
                return candidate.resolve(strict=True)
        except (OSError, RuntimeError, ValueError):
            continue
    raise arm_error(spec, f"mesh {written!r} not found (searched {', '.join(map(str, roots))})")


def _arm_joints(spec: Arm, model: Any) -> list[int]:
    """The ids of the arm's joints: `spec.joint_names`, else every joint from the root to the
    tip link; refused unless they are one chain ending at the tip, each of one coordinate."""
    chain = []
    joint = int(model.frames[model.getFrameId(spec.tip_link)].parentJoint)
    while joint > 0:
        chain.append(joint)
        joint = int(model.parents[joint])
    chain.reverse()
    if not spec.joint_names:
        if not chain:
            raise arm_error(spec, f"no moving joint between the root and {spec.tip_link!r}")
        return chain
    ids = []
    for name in spec.joint_names:
        if not model.existJointName(name):
            raise arm_error(spec, f"no joint {name!r}")
        index = int(model.getJointId(name))
        if index not in chain:
            raise arm_error(spec, f"joint {name!r} does not move {spec.tip_link!r}")
        ids.append(index)
    if ids != sorted(ids):
        raise arm_error(spec, "joint_names must follow the chain from the root to the tip")
    return ids


def _per_joint(spec: Arm, name: str, values: Any, count: int) -> np.ndarray:
    """One value per joint (a single value is every joint's)."""
    array = np.asarray(values, dtype=float).reshape(-1)
    if len(array) == 1:
        array = np.full(count, array[0])
    if len(array) != count or not np.isfinite(array).all():
        raise arm_error(spec, f"{name} needs {count} finite values, got {len(array)}")
    return array


def _limits(spec: Arm, model: Any) -> tuple[np.ndarray, ...]:
    """lower, upper, velocity, acceleration, jerk, effort and home, one value per joint."""
    n = model.nq
    lower = np.array(model.lowerPositionLimit, dtype=float)
    upper = np.array(model.upperPositionLimit, dtype=float)
    if spec.position_limits is not None:
        bounds = _per_joint(spec, "position_limits", spec.position_limits, 2 * n).reshape(n, 2)
        lower, upper = bounds[:, 0], bounds[:, 1]
    velocity = np.array(model.velocityLimit, dtype=float)
    if spec.velocity_limits is not None:
        velocity = _per_joint(spec, "velocity_limits", spec.velocity_limits, n)
    acceleration = _per_joint(
        spec, "acceleration_limits", spec.acceleration_limits or [DEFAULT_ACCELERATION] * n, n
    )
    jerk = _per_joint(spec, "jerk_limits", spec.jerk_limits or [DEFAULT_JERK] * n, n)
    effort = np.array(model.effortLimit, dtype=float)
    if spec.effort_limits is not None:
        effort = _per_joint(spec, "effort_limits", spec.effort_limits, n)
    names = [model.names[j] for j in range(1, model.njoints)]
    for label, values in (("velocity", velocity), ("acceleration", acceleration), ("jerk", jerk)):
        if np.any(values <= 0):
            joint = names[int(np.argmin(values))]
            raise arm_error(spec, f"joint {joint!r} has no {label} limit (give {label}_limits)")
    if np.any(lower >= upper):
        raise arm_error(spec, f"joint {names[int(np.argmax(lower - upper))]!r} cannot move")
    home = np.zeros(n) if spec.home is None else _per_joint(spec, "home", spec.home, n)
    if np.any(home < lower) or np.any(home > upper):
        raise arm_error(spec, "the home configuration is outside the joint limits")
    return lower, upper, velocity, acceleration, jerk, effort, home
