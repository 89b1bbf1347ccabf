"""The `rosbag` executor: the validated trajectory as a ROS 2 bag (MCAP storage).

Topics: the whole trajectory as one trajectory_msgs/msg/JointTrajectory (header stamp zero,
which a joint_trajectory_controller reads as "start on receipt"; every point's
time_from_start exact to the ns), the planned tool path as one nav_msgs/msg/Path in the
board frame, and optionally sensor_msgs/msg/JointState at every sample's time for previews.
Written with the pure-Python rosbags library; `ros2 bag play` sends it (docs/exporters.md).
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, ConfigDict

from keymps._version import __version__ as keymps_version
from keymps.errors import KeympsError
from keymps.plugin import RunFolderPath, parse_options, require_validated, trajectory_digest
from keymps.types import ExecutionReport, Trajectory
from keymps_ros.messages import NamePart, RosName, durations, joint_names, quaternions_xyzw

if TYPE_CHECKING:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys.store import Typestore

    from keymps.run import Run

NAME = "rosbag"
JOINT_TRAJECTORY = "trajectory_msgs/msg/JointTrajectory"
PATH = "nav_msgs/msg/Path"
JOINT_STATE = "sensor_msgs/msg/JointState"
BAG_FILES = (".mcap", ".yaml")
"""What a folder holds when it is a bag this executor may replace."""


class RosbagOptions(BaseModel):
    """The executor section of a task file for `rosbag` (every key but `name`)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True)

    bag: RunFolderPath = Path("trajectory_bag")
    """The bag's folder in the run folder (metadata.yaml and one .mcap file)."""
    trajectory_topic: RosName = "/joint_trajectory"
    path_topic: RosName | None = "/tool_path"
    """null: no tool path."""
    joint_states_topic: RosName | None = None
    """JointState at every sample's time (null: none). Not on a live robot's /joint_states."""
    frame_id: NamePart = "board"
    """The tool path's frame: keymps' board frame (docs/tasks.md)."""
    joint_prefix: NamePart = ""
    """Put before every joint name, as the robot's driver names them (its tf_prefix)."""


class RosbagExecutor:
    """Writes a ROS 2 bag; moves nothing."""

    name = NAME

    def __init__(self, options: RosbagOptions):
        self.options = options

    def execute(self, validated: Any, run: Run) -> ExecutionReport:
        from keymps.robot.identity import arm_identity

        trajectory = require_validated(validated, self.name)
        arm = arm_identity(run)
        if tuple(trajectory.joint_names) != arm.joint_names:
            raise KeympsError(
                f"executor rosbag: the trajectory's joints ({', '.join(trajectory.joint_names)})"
                f" are not the {arm.model}'s ({', '.join(arm.joint_names)})"
            )
        target = run.path(str(self.options.bag))
        metadata = {
            "keymps_version": keymps_version,
            "task": run.task.name,
            "trajectory_sha256": trajectory_digest(trajectory),
            "robot_model": arm.model,
        }
        counts = replace_bag(target, lambda folder: self._write(folder, trajectory, run, metadata))
        topics = ", ".join(f"{topic} ({count})" for topic, count in counts.items())
        return ExecutionReport(
            self.name,
            True,
            f"wrote {target} (MCAP: {topics}); nothing was sent to a robot",
            (str(target),),
            {"duration_s": trajectory.duration_s, "samples": float(trajectory.samples)},
        )

    def _write(
        self, folder: Path, trajectory: Trajectory, run: Run, metadata: dict[str, str]
    ) -> dict[str, int]:
        from rosbags.rosbag2 import StoragePlugin, Writer

        options, store = self.options, typestore()
        start = time.time_ns()
        stamps = start + (np.asarray([s * 1_000_000_000 + n for s, n in durations(trajectory.t)]))
        counts = {}
        with Writer(folder, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
            for key, value in metadata.items():
                writer.set_custom_data(key, value)
            message = joint_trajectory(store, trajectory, options.joint_prefix)
            counts[options.trajectory_topic] = _put(
                writer, store, options.trajectory_topic, [(start, message)]
            )
            if options.path_topic is not None:
                path = tool_path(store, trajectory, run, options.frame_id, stamps)
                counts[options.path_topic] = _put(
                    writer, store, options.path_topic, [(start, path)]
                )
            if options.joint_states_topic is not None:
                states = joint_states(store, trajectory, options.joint_prefix, stamps)
                counts[options.joint_states_topic] = _put(
                    writer,
                    store,
                    options.joint_states_topic,
                    zip(stamps.tolist(), states, strict=True),
                )
        return counts


def typestore() -> Typestore:
    """ROS 2 Humble's message definitions (the same as Jazzy's and Kilted's for these)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _put(writer: Writer, store: Typestore, topic: str, messages: Any) -> int:
    """Write (log time ns, message) pairs on `topic`; how many."""
    count, connection = 0, None
    for stamp, message in messages:
        if connection is None:
            connection = writer.add_connection(topic, message.__msgtype__, typestore=store)
        writer.write(connection, int(stamp), store.serialize_cdr(message, message.__msgtype__))
        count += 1
    return count


def _time(store: Typestore, ns: int) -> Any:
    seconds, nanoseconds = divmod(int(ns), 1_000_000_000)
    return store.types["builtin_interfaces/msg/Time"](sec=seconds, nanosec=nanoseconds)


def _header(store: Typestore, ns: int, frame: str) -> Any:
    return store.types["std_msgs/msg/Header"](stamp=_time(store, ns), frame_id=frame)


def joint_trajectory(store: Typestore, trajectory: Trajectory, prefix: str) -> Any:
    """One JointTrajectory with every sample (positions, velocities, accelerations)."""
    types = store.types
    point, duration = (
        types["trajectory_msgs/msg/JointTrajectoryPoint"],
        types["builtin_interfaces/msg/Duration"],
    )
    q, qd, qdd = (np.asarray(a, dtype=np.float64) for a in (trajectory.q, trajectory.qd,
                                                              trajectory.qdd))  # fmt: skip
    points = [
        point(
            positions=q[i].copy(),
            velocities=qd[i].copy(),
            accelerations=qdd[i].copy(),
            effort=np.empty(0, dtype=np.float64),
            time_from_start=duration(sec=sec, nanosec=nanosec),
        )
        for i, (sec, nanosec) in enumerate(durations(trajectory.t))
    ]
    return types[JOINT_TRAJECTORY](
        header=_header(store, 0, ""), joint_names=joint_names(trajectory, prefix), points=points
    )


def tool_path(
    store: Typestore, trajectory: Trajectory, run: Run, frame: str, stamps: np.ndarray
) -> Any:
    """The planned tool-tip path (board frame), each pose stamped with its sample's time; the
    orientations are the arm's tool frame at each sample (forward kinematics)."""
    from keymps.robot.identity import tool_poses

    types = store.types
    _, rotations = tool_poses(run, np.asarray(trajectory.q, dtype=float))
    quaternions = quaternions_xyzw(rotations)
    point, quaternion = types["geometry_msgs/msg/Point"], types["geometry_msgs/msg/Quaternion"]
    pose, stamped = types["geometry_msgs/msg/Pose"], types["geometry_msgs/msg/PoseStamped"]
    poses = [
        stamped(
            header=_header(store, stamp, frame),
            pose=pose(position=point(x=x, y=y, z=z), orientation=quaternion(x=a, y=b, z=c, w=d)),
        )
        for stamp, (x, y, z), (a, b, c, d) in zip(
            stamps.tolist(),
            np.asarray(trajectory.tool_xyz, dtype=float).tolist(),
            quaternions.tolist(),
            strict=True,
        )
    ]
    return types[PATH](header=_header(store, int(stamps[0]), frame), poses=poses)


def joint_states(
    store: Typestore, trajectory: Trajectory, prefix: str, stamps: np.ndarray
) -> list[Any]:
    """One JointState per sample (position and velocity), stamped with its time."""
    state, names = store.types[JOINT_STATE], joint_names(trajectory, prefix)
    q, qd = np.asarray(trajectory.q, dtype=np.float64), np.asarray(trajectory.qd, np.float64)
    return [
        state(
            header=_header(store, stamp, ""),
            name=names,
            position=q[i].copy(),
            velocity=qd[i].copy(),
            effort=np.empty(0, dtype=np.float64),
        )
        for i, stamp in enumerate(stamps.tolist())
    ]


def replace_bag(target: Path, write: Any) -> Any:
    """`write(folder)` into a new folder named like `target` (rosbags names the .mcap file
    after it) in a hidden one beside it, then put it in target's place: a bag already there,
    from an earlier export, is replaced; anything else is refused."""
    if target.exists() and not _is_bag(target):
        raise KeympsError(
            f"executor rosbag: {target} exists and is not a bag: choose another executor.bag"
        )
    scratch = target.with_name(f".{target.name}.{os.getpid()}-{os.urandom(4).hex()}.tmp")
    try:
        scratch.mkdir()
        result = write(scratch / target.name)
        if target.exists():
            shutil.rmtree(target)
        (scratch / target.name).rename(target)
    except OSError as error:
        raise KeympsError(f"executor rosbag: cannot write {target}: {error.strerror}") from None
    except Exception as error:  # rosbags' WriterError and the like
        raise KeympsError(f"executor rosbag: cannot write {target}: {error}") from None
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return result


def _is_bag(folder: Path) -> bool:
    if folder.is_symlink() or not folder.is_dir():
        return False
    entries = list(folder.iterdir())
    return (folder / "metadata.yaml").is_file() and all(
        entry.is_file() and not entry.is_symlink() and entry.suffix in BAG_FILES
        for entry in entries
    )


def make_executor(options: dict[str, Any]) -> RosbagExecutor:
    return RosbagExecutor(parse_options(RosbagOptions, options, "executor rosbag"))
