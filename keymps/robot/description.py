"""The UR arms keymps knows (DH lengths, URDF, joint speed limits) and the tools on them.

The kinematic model is the UR3 URDF shipped by the example-robot-data wheel, with its link
lengths set to the arm's standard DH table (exact for both the UR3 and the UR3e), its root
placed in the board frame and a `tcp` frame at the tool tip.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.errors import KeympsError

if TYPE_CHECKING:
    from keymps.config.task import Task

JOINT_NAMES: tuple[str, ...] = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)

POSITION_TOLERANCE_M = 1e-4
ROTATION_TOLERANCE_RAD = math.radians(0.1)
REACH_MARGIN_M = 0.01
"""Keep the wrist this far inside the fully stretched arm (a stretched elbow is singular)."""


@dataclass(frozen=True)
class ArmGeometry:
    """Standard DH lengths of a UR arm (metres); the URDF is rescaled to these."""

    d1: float
    upper_arm: float
    forearm: float
    d4: float
    d5: float
    d6: float
    joint_speed_limits: tuple[float, ...]
    rate_hz: float


_DEG = math.pi / 180.0
_UR_JOINT_SPEEDS = (180 * _DEG, 180 * _DEG, 180 * _DEG, 360 * _DEG, 360 * _DEG, 360 * _DEG)

ARMS: dict[str, ArmGeometry] = {
    "ur3": ArmGeometry(0.1519, 0.24365, 0.21325, 0.11235, 0.08535, 0.0819, _UR_JOINT_SPEEDS, 125.0),
    "ur3e": ArmGeometry(
        0.15185, 0.24355, 0.2132, 0.13105, 0.08535, 0.0921, _UR_JOINT_SPEEDS, 500.0
    ),
}


@dataclass(frozen=True)
class Tool:
    """A tool on the flange: its tip in the flange frame and how its yaw is chosen."""

    name: str
    tcp: tuple[float, float, float]
    yaw: str
    """'follow': the tool turns with the path direction (a blade); 'fixed': constant yaw."""
    blade_length: float = 0.0
    """A straight horizontal edge along the tool x axis, from the tip back against the direction
    of travel, metres (0: no blade). The sim executor cuts with the whole edge."""
    line_width: float = 0.0
    """Width of the line an icing tool draws, metres (0: not an icing tool)."""


BUILTIN_TOOLS: dict[str, Tool] = {
    "knife": Tool("knife", (0.0, 0.0, 0.10), "follow", blade_length=0.16),  # a chef's knife
    "piping_bag": Tool("piping_bag", (0.0, 0.0, 0.15), "fixed", blade_length=0.0, line_width=0.004),
}


def tool_from_task(task: Task) -> Tool:
    """The task's tool: a built-in by name, possibly with its own TCP, yaw mode and blade."""
    spec = task.robot.tool
    builtin = BUILTIN_TOOLS.get(spec.name)
    if builtin is None and spec.tcp is None:
        choices = ", ".join(sorted(BUILTIN_TOOLS))
        raise KeympsError(
            f"robot.tool: unknown tool {spec.name!r}; use a built-in ({choices}) "
            "or give its tcp: [x, y, z] (tool tip in the flange frame, metres)"
        )
    tcp = tuple(float(v) for v in spec.tcp) if spec.tcp is not None else builtin.tcp  # type: ignore[union-attr]
    yaw = spec.yaw or (builtin.yaw if builtin else "fixed")
    blade = spec.blade_length
    if blade is None:
        blade = builtin.blade_length if builtin else 0.0
    line = spec.line_width
    if line is None:
        line = builtin.line_width if builtin else 0.0
    return Tool(spec.name, (tcp[0], tcp[1], tcp[2]), yaw, float(blade), float(line))


def ur_urdf_path() -> Path:
    """The UR3 URDF shipped (with meshes) by the example-robot-data wheel."""
    relative = "cmeel.prefix/share/example-robot-data/robots/ur_description/urdf/ur3_robot.urdf"
    try:
        path = Path(str(metadata.distribution("example-robot-data").locate_file(relative)))
    except metadata.PackageNotFoundError:
        raise KeympsError(
            "the example-robot-data package is not installed (pip install example-robot-data)"
        ) from None
    if not path.is_file():
        raise KeympsError(f"example-robot-data is installed but {path} is missing")
    return path


def tool_rotation(yaw: float) -> np.ndarray:
    """Tool orientation in the board frame: pointing down, x axis at `yaw` about board z."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])


def se3(rotation: np.ndarray, translation: np.ndarray) -> Any:
    import pinocchio as pin

    return pin.SE3(np.asarray(rotation, dtype=float), np.asarray(translation, dtype=float))


def rz(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def build_pinocchio_model(arm: ArmGeometry, base_in_board: Any, tool: Tool) -> tuple[Any, int]:
    """The UR3 URDF, its lengths set to `arm`, its base in the board frame, a 'tcp' frame."""
    import pinocchio as pin

    model = pin.buildModelFromUrdf(str(ur_urdf_path()))
    ids = {name: model.getJointId(name) for name in JOINT_NAMES}
    # The URDF splits d4 over three lateral offsets (0.1198 - 0.0925 + 0.08505); the last one
    # absorbs the e-Series difference, which keeps the kinematics exact.
    translations = {
        "shoulder_pan_joint": (0.0, 0.0, arm.d1),
        "elbow_joint": (0.0, -0.0925, arm.upper_arm),
        "wrist_1_joint": (0.0, 0.0, arm.forearm),
        "wrist_2_joint": (0.0, arm.d4 - 0.1198 + 0.0925, 0.0),
        "wrist_3_joint": (0.0, 0.0, arm.d5),
    }
    for name, translation in translations.items():
        placement = model.jointPlacements[ids[name]].copy()
        placement.translation = np.array(translation)
        model.jointPlacements[ids[name]] = placement
    pan = ids["shoulder_pan_joint"]
    model.jointPlacements[pan] = base_in_board * model.jointPlacements[pan]
    tool0 = model.frames[model.getFrameId("tool0")]
    flange = tool0.placement.copy()
    flange.translation = np.array([0.0, arm.d6, 0.0])
    tcp = flange * se3(np.eye(3), np.array(tool.tcp))
    frame_id = model.addFrame(
        pin.Frame("tcp", tool0.parentJoint, tool0.parentFrame, tcp, pin.FrameType.OP_FRAME)
    )
    model.addFrame(
        pin.Frame("flange", tool0.parentJoint, tool0.parentFrame, flange, pin.FrameType.OP_FRAME)
    )
    return model, frame_id
