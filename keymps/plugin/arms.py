"""What a robot plugin describes: an arm as its URDF plus the numbers a URDF does not hold.

A `register_robots` factory returns an `ArmSpec` (or any object with the same attributes, the
`Arm` Protocol of keymps.plugin.components). keymps builds the arm's Pinocchio model, collision
model, inverse kinematics, timing limits, drawings and MuJoCo model from it; nothing here
imports Pinocchio.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

Pose4 = tuple[float, float, float, float]
"""x, y, z (metres) and yaw (degrees) of the arm's root link in the board frame."""


@dataclass(frozen=True)
class ArmSpec:
    """A robot arm: its URDF, the frame its tool is mounted on, and its limits.

    Joint vectors follow `joint_names` (the controller's order); per-joint tuples have one
    value per joint (or one value for every joint). Angles in radians, lengths in metres.
    """

    name: str
    """The model name a task file gives as `robot.model` ("ur5e", "panda")."""
    urdf: Path
    """The arm's URDF file (its collision shapes are the safety check's collision model)."""
    tip_link: str
    """The frame the tool is mounted on: `robot.tool.tcp` is given in it and its z axis is the
    direction the tool points (the flange, a gripper's tool centre point)."""
    joint_names: tuple[str, ...] = ()
    """The arm's joints, in the controller's order; () takes every moving joint between the
    URDF's root and `tip_link`. Other moving joints (a gripper's) are held at their neutral
    position."""
    velocity_limits: tuple[float, ...] | None = None
    """rad/s per joint; None takes the URDF's `<limit velocity=...>`."""
    acceleration_limits: tuple[float, ...] | None = None
    """rad/s^2 per joint; None: DEFAULT_ACCELERATION for every joint (URDFs hold none)."""
    jerk_limits: tuple[float, ...] | None = None
    """rad/s^3 per joint; None: DEFAULT_JERK for every joint."""
    position_limits: tuple[tuple[float, float], ...] | None = None
    """(lower, upper) per joint; None takes the URDF's."""
    effort_limits: tuple[float, ...] | None = None
    """N m per joint, what a physics simulation may command; None takes the URDF's."""
    home: tuple[float, ...] | None = None
    """A configuration with the tool pointing down over the board when the arm stands at
    `base_for(board)`: where the inverse kinematics starts. None: the URDF's zero."""
    standoff: float = 0.20
    """The default placement: the root link this far in front of the board's near edge (its
    y = 0 side), centred on the board's width, facing the board (yaw 90 degrees)."""
    mount_height: float = 0.0
    """The root link's height above the board surface in the default placement."""
    rate_hz: float = 125.0
    """The controller's rate, the trajectory's sample rate when the task gives none."""
    dh: tuple[float, float, float, float, float, float] | None = None
    """(d1, a2, a3, d4, d5, d6) of a Universal Robots-type arm (standard DH, alpha = pi/2, 0,
    0, pi/2, -pi/2, 0): the URDF's lengths are set to these and the closed-form inverse
    kinematics is used. None: the iterative inverse kinematics."""
    package_dirs: tuple[Path, ...] = ()
    """Folders in which the URDF's `package://NAME/...` mesh paths are looked up (the
    URDF's own folder and its parents are always searched). No mesh outside them is read."""
    collision_padding: float = 0.0
    """Metres added to every clearance the safety check demands, for a collision model
    smaller than the real arm."""
    mesh_scales: tuple[tuple[str, tuple[float, float, float]], ...] = ()
    """(link name, (sx, sy, sz)) extra scale of a link's meshes (stretching a shared mesh to
    another model's lengths)."""
    description: str = ""
    """One line for `keymps plugins` and error messages ("Universal Robots UR5e")."""

    def base_for(self, board_size: tuple[float, float]) -> Pose4:
        """The default placement on a board.

        Args:
            board_size: The board's (width, height), metres.

        Returns:
            (x, y, z, yaw): metres and degrees of the root link in the board frame, `standoff`
            in front of the middle of the near edge, raised by `mount_height`, facing the board.
        """
        return (board_size[0] / 2.0, -self.standoff, self.mount_height, 90.0)


DEFAULT_ACCELERATION = 3.0
"""rad/s^2: the joint acceleration limit of an arm whose maker publishes none (the UR arms)."""
DEFAULT_JERK = 100.0
"""rad/s^3: the joint jerk limit of an arm whose maker publishes none."""


def degrees(*values: float) -> tuple[float, ...]:
    """Degrees to radians, for limit tables written as the makers publish them.

    Args:
        values: Angles or angular speeds in degrees (per second).

    Returns:
        The same in radians.
    """
    return tuple(math.radians(v) for v in values)
