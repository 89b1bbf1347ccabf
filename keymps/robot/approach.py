"""The move a real-arm executor adds itself, from the arm's pose to a validated trajectory's
first sample (a controller moveJ), checked by the same rules as the trajectory."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from keymps.errors import SafetyError
from keymps.robot.safety import check_board, check_joints, check_workspace
from keymps.types import Piece, ToolPath, Trajectory, ValidationReport

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.robot.model import RobotModel


def move_j_profile(
    q_from: np.ndarray, q_to: np.ndarray, speed: float, acceleration: float, rate_hz: float
) -> Trajectory:
    """The joint motion of a controller's moveJ from q_from to q_to: every joint on one
    trapezoidal profile, the joint that moves most at `speed` rad/s and `acceleration` rad/s^2
    (what URScript's movej does), sampled at `rate_hz`; tool_xyz is left at zero."""
    q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
    delta = q_to - q_from
    largest = float(np.abs(delta).max())
    ramp = speed / acceleration
    if largest <= speed * ramp:  # never reaches full speed: a triangle
        ramp = math.sqrt(largest / acceleration)
        duration = 2 * ramp
    else:
        duration = largest / speed + ramp
    count = max(2, math.ceil(duration * rate_hz) + 1)
    t = np.arange(count) / rate_hz
    top = largest / (duration - ramp) if duration > ramp else 0.0  # reached speed, rad/s
    a = top / ramp if ramp > 0 else 0.0
    tc = np.clip(t, 0.0, duration)
    s = np.where(
        tc < ramp,
        0.5 * a * tc**2,
        np.where(
            tc <= duration - ramp,
            0.5 * a * ramp**2 + top * (tc - ramp),
            largest - 0.5 * a * (duration - tc) ** 2,
        ),
    )
    sd = np.where(tc < ramp, a * tc, np.where(tc <= duration - ramp, top, a * (duration - tc)))
    sdd = np.where(tc < ramp, a, np.where(tc <= duration - ramp, 0.0, -a))
    unit = delta / largest if largest > 0 else np.zeros(6)
    sd[[0, -1]] = 0.0
    sdd[[0, -1]] = 0.0
    return Trajectory(
        t=t,
        q=q_from + s[:, None] * unit,
        qd=sd[:, None] * unit,
        qdd=sdd[:, None] * unit,
        tool_xyz=np.zeros((count, 3)),
        piece_index=np.zeros(count, dtype=int),
        kind=np.full(count, "travel"),
        joint_names=(),
        rate_hz=rate_hz,
    )


def check_approach(
    model: RobotModel,
    q_from: np.ndarray,
    q_to: np.ndarray,
    task: Task,
    *,
    speed: float,
    acceleration: float,
    rate_hz: float,
) -> ValidationReport:
    """The move from the arm's pose to a validated trajectory's first sample (a moveJ a real
    executor sends) checked like the trajectory: joint limits, joint speed and acceleration,
    the workspace and the board (tool tip and arm). Jerk and tool tilt are not checked: moveJ
    is the controller's trapezoid, and the arm may start tilted. Raises SafetyError."""
    move = move_j_profile(q_from, q_to, speed, acceleration, rate_hz)
    positions, rotations, origins = model.tool_poses_and_joint_origins(move.q)
    move = replace(move, tool_xyz=positions, joint_names=tuple(model.joint_names))
    path = ToolPath((Piece("travel", 0, positions, np.zeros(len(positions)), speed),), "approach")
    problems: list[str] = []
    figures: dict[str, float] = {"duration_s": move.duration_s}
    joint_problems: list[str] = []
    check_joints(model, move, joint_problems, figures)
    problems += [p for p in joint_problems if " jerk " not in p]
    board: list[str] = []
    check_board(move, positions, rotations, origins, board, figures)
    problems += [p for p in board if "tilts" not in p]
    check_workspace(move, path, positions, task, problems, figures)
    if problems:
        raise SafetyError([f"the move to the first sample: {p}" for p in problems])
    return ValidationReport(True, (), figures)
