"""The Universal Robots DH lengths (for the closed-form IK) and the tools on an arm's flange."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.errors import KeympsError
from keymps.robot.catalog import UR_ARMS, example_robot_data

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


def ur_geometry(dh: tuple[float, ...], speeds: tuple[float, ...], rate_hz: float) -> ArmGeometry:
    """The ArmGeometry of a UR-type DH table (d1, a2, a3, d4, d5, d6; a2, a3 negative)."""
    d1, a2, a3, d4, d5, d6 = (float(v) for v in dh)
    return ArmGeometry(d1, -a2, -a3, d4, d5, d6, tuple(speeds), rate_hz)


ARMS: dict[str, ArmGeometry] = {
    name: ur_geometry(table["dh"], table["speed"], table["rate"])  # type: ignore[arg-type]
    for name, table in UR_ARMS.items()
}
"""The DH lengths of the Universal Robots arms keymps ships (keymps.robot.catalog)."""


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


def ur_urdf_path(name: str = "ur3") -> Path:
    """A UR URDF shipped (with meshes) by the example-robot-data wheel."""
    return example_robot_data(f"ur_description/urdf/{name}_robot.urdf")


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
