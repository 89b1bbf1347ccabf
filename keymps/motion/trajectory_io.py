"""Trajectory files: the run folder's CSV and a JSON in the shape of a ROS JointTrajectory."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from keymps.errors import KeympsError
from keymps.run import write_atomically
from keymps.types import Trajectory

CSV_HEADER = "t,q1,q2,q3,q4,q5,q6,x,y,z,piece,kind"


def write_trajectory_csv(trajectory: Trajectory, path: str | Path) -> Path:
    """One row per controller sample: seconds, radians, tool tip metres (board), piece, kind."""
    path = Path(path)
    row = ",".join(["%.6f"] + ["%.9f"] * 6 + ["%.6f"] * 3 + ["%d", "%s"])
    numbers = np.column_stack([trajectory.t, trajectory.q, trajectory.tool_xyz]).tolist()
    pieces = np.asarray(trajectory.piece_index).astype(int).tolist()
    kinds = [str(kind) for kind in trajectory.kind]
    rows = [
        row % (*values, piece, kind)
        for values, piece, kind in zip(numbers, pieces, kinds, strict=True)
    ]
    _write_text(path, "\n".join([CSV_HEADER, *rows]) + "\n")
    return path


def read_trajectory_csv(path: str | Path) -> dict[str, np.ndarray]:
    """The columns of a trajectory CSV: t (n,), q (n, 6), xyz (n, 3), piece (n,), kind (n,)."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as error:
        raise KeympsError(f"{path}: cannot read: {error.strerror}") from None
    if not lines or lines[0].strip() != CSV_HEADER:
        raise KeympsError(f"{path}:1: expected the header {CSV_HEADER}")
    numbers, kinds = [], []
    for number, line in enumerate(lines[1:], start=2):
        fields = line.split(",")
        try:
            if len(fields) != 12:
                raise ValueError(f"{len(fields)} fields instead of 12")
            numbers.append([float(v) for v in fields[:11]])
        except ValueError as error:
            raise KeympsError(f"{path}:{number}: {error}") from None
        kinds.append(fields[11].strip())
    table = np.array(numbers, dtype=float).reshape(-1, 11)
    return {
        "t": table[:, 0],
        "q": table[:, 1:7],
        "xyz": table[:, 7:10],
        "piece": table[:, 10].astype(int),
        "kind": np.array(kinds),
    }


def joint_trajectory_message(trajectory: Trajectory) -> dict[str, object]:
    """trajectory_msgs/JointTrajectory as plain data (header left for the consumer to stamp)."""
    t = np.asarray(trajectory.t, dtype=float)
    seconds = np.floor(t)
    nanoseconds = np.round((t - seconds) * 1e9)
    carry = nanoseconds >= 1_000_000_000
    seconds, nanoseconds = seconds + carry, nanoseconds - carry * 1_000_000_000
    points = [
        {
            "positions": q,
            "velocities": qd,
            "accelerations": qdd,
            "effort": [],
            "time_from_start": {"sec": sec, "nanosec": nanosec},
        }
        for q, qd, qdd, sec, nanosec in zip(
            np.asarray(trajectory.q, dtype=float).tolist(),
            np.asarray(trajectory.qd, dtype=float).tolist(),
            np.asarray(trajectory.qdd, dtype=float).tolist(),
            seconds.astype(int).tolist(),
            nanoseconds.astype(int).tolist(),
            strict=True,
        )
    ]
    return {
        "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""},
        "joint_names": list(trajectory.joint_names),
        "points": points,
    }


def write_joint_trajectory_json(trajectory: Trajectory, path: str | Path) -> Path:
    """The trajectory as a ROS 2 JointTrajectory message in JSON."""
    path = Path(path)
    _write_text(path, json.dumps(joint_trajectory_message(trajectory), separators=(",", ":")))
    return path


def _write_text(path: Path, text: str) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomically(path, text)
    except OSError as error:
        raise KeympsError(f"{path}: cannot write: {error.strerror}") from None
