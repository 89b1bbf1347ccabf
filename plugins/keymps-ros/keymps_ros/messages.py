"""What the ROS executors share: option checks for ROS names, and the trajectory's numbers in
ROS's units (nanosecond durations, prefixed joint names, tool orientations as quaternions)."""

from __future__ import annotations

import re
from typing import Annotated

import numpy as np
from pydantic import AfterValidator

from keymps.types import Trajectory

_NAME = re.compile(r"/[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*")


def _absolute_name(name: str) -> str:
    if not _NAME.fullmatch(name):
        raise ValueError(
            f"{name!r} is not an absolute ROS name (like /joint_trajectory: '/', then letters, "
            "digits and '_' in parts separated by '/')"
        )
    return name


def _name_part(text: str) -> str:
    if not re.fullmatch(r"[A-Za-z0-9_]*", text):
        raise ValueError(f"{text!r} may hold only letters, digits and '_'")
    return text


RosName = Annotated[str, AfterValidator(_absolute_name)]
"""A topic or action name option: absolute, ROS's characters only."""
NamePart = Annotated[str, AfterValidator(_name_part)]
"""A joint-name prefix or a frame id option."""


def joint_names(trajectory: Trajectory, prefix: str) -> list[str]:
    """The trajectory's joint names as the robot's ROS driver names them."""
    return [f"{prefix}{name}" for name in trajectory.joint_names]


def durations(t: np.ndarray) -> list[tuple[int, int]]:
    """(sec, nanosec) of each time from the trajectory's first sample (rounded to the ns)."""
    from keymps.motion.trajectory_io import time_from_start_ns

    ns = time_from_start_ns(np.asarray(t, dtype=float) - float(t[0]))
    seconds, nanoseconds = np.divmod(ns, 1_000_000_000)
    return list(zip(seconds.tolist(), nanoseconds.tolist(), strict=True))


def quaternions_xyzw(rotations: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions (x, y, z, w; w >= 0) of (n, 3, 3) rotation matrices."""
    r = np.asarray(rotations, dtype=float).reshape(-1, 3, 3)
    m = {(i, j): r[:, i, j] for i in range(3) for j in range(3)}
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    # 4 w^2, 4 x^2, 4 y^2, 4 z^2 from the diagonal: the largest gives a well-conditioned division
    squares = np.column_stack(
        [1 + trace, 1 + m[0, 0] - m[1, 1] - m[2, 2], 1 - m[0, 0] + m[1, 1] - m[2, 2]]
        + [1 - m[0, 0] - m[1, 1] + m[2, 2]]
    )
    largest = np.argmax(squares, axis=1)
    s = 2.0 * np.sqrt(np.maximum(squares[np.arange(len(r)), largest], 1e-300))  # 4 * that one
    wx, wy, wz = m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]  # 4wx, 4wy, 4wz
    xy, xz, yz = m[0, 1] + m[1, 0], m[0, 2] + m[2, 0], m[1, 2] + m[2, 1]  # 4xy, 4xz, 4yz
    by_largest = [  # (x, y, z, w) * s, for w, x, y, z largest
        (wx, wy, wz, 0.25 * s * s),
        (0.25 * s * s, xy, xz, wx),
        (xy, 0.25 * s * s, yz, wy),
        (xz, yz, 0.25 * s * s, wz),
    ]
    q = np.empty((len(r), 4))
    for k, components in enumerate(by_largest):
        rows = largest == k
        q[rows] = np.column_stack([c[rows] for c in components]) / s[rows, None]
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)
