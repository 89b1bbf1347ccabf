"""keymps-ros: keymps trajectories for ROS 2, as a bag (`rosbag`) or a live goal (`ros2`).

This module is what keymps loads for every command: it only registers the factories. Each
executor (and rosbags or roslibpy with it) is imported when a task first uses it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from keymps.plugin import RegisterExecutor, hookimpl

if TYPE_CHECKING:
    from keymps_ros.live import Ros2Executor
    from keymps_ros.rosbag import RosbagExecutor

__version__ = "0.1.0"


def make_rosbag_executor(options: dict[str, Any]) -> RosbagExecutor:
    from keymps_ros.rosbag import make_executor

    return make_executor(options)


def make_ros2_executor(options: dict[str, Any]) -> Ros2Executor:
    from keymps_ros.live import make_executor

    return make_executor(options)


@hookimpl
def register_executors(register: RegisterExecutor) -> None:
    register("rosbag", make_rosbag_executor)
    register("ros2", make_ros2_executor)
