"""What exporters read of the run's arm: its model, maker, joint names and controller rate.

The URScript, rosbag and ROS 2 executors learn about the arm only through `arm_identity` and
`tool_poses`, so a new kind of arm changes these two functions, not the exporters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from keymps.robot.description import ARMS, JOINT_NAMES

__all__ = ["JOINT_NAMES", "UNIVERSAL_ROBOTS", "ArmIdentity", "arm_identity", "tool_poses"]

if TYPE_CHECKING:
    from keymps.robot.model import RobotModel
    from keymps.run import Run

UNIVERSAL_ROBOTS = "Universal Robots"


@dataclass(frozen=True)
class ArmIdentity:
    """The run's arm as an exported file names it."""

    model: str
    """The task's robot.model, e.g. `ur3e`."""
    maker: str
    """Who builds it, e.g. `Universal Robots`: URScript runs only on that maker's controllers."""
    joint_names: tuple[str, ...]
    """The joints in the order of the trajectory's columns (ROS names, no prefix)."""
    controller_hz: float
    """The controller's own cycle rate, Hz (125 for a UR CB3, 500 for an e-Series)."""
    generation: str
    """The controller generation, e.g. `CB3` or `e-Series`."""


def arm_identity(run: Run) -> ArmIdentity:
    """The arm `run` planned for (`run.robot`, else the arm the task's robot section names)."""
    robot = run.robot
    if robot is None:
        from keymps.robot.model import RobotModel

        robot = RobotModel.from_task(run.task)
    model = robot.model_name
    universal = model in ARMS
    return ArmIdentity(
        model=model,
        maker=UNIVERSAL_ROBOTS if universal else (robot.spec.description or model),
        joint_names=tuple(robot.joint_names),
        controller_hz=float(robot.rate_hz),
        generation=("e-Series" if model.endswith("e") or model == "ur20" else "CB3")
        if universal
        else "",
    )


def tool_poses(run: Run, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) tool-tip positions and (n, 3, 3) rotations in the board frame for (n, 6) joint
    vectors, by the run's arm (built from the task when the run has none)."""
    robot: RobotModel
    if run.robot is not None:
        robot = run.robot
    else:
        from keymps.robot.model import RobotModel

        robot = RobotModel.from_task(run.task)
    return robot.tool_poses(np.asarray(q, dtype=float))
