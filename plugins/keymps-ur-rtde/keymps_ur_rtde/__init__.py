"""keymps-ur-rtde: run keymps trajectories on a real Universal Robots arm (ur_rtde).

This module is what keymps loads for every command: it only registers the factory. The
executor is imported when a task first uses it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from keymps.plugin import RegisterExecutor, hookimpl

if TYPE_CHECKING:
    from keymps_ur_rtde.executor import UrRtdeExecutor

__version__ = "0.1.0"

NAME = "ur-rtde"
"""The executor's name (`executor.name`, `--executor`)."""


def make_executor(options: dict[str, Any]) -> UrRtdeExecutor:
    from keymps_ur_rtde.executor import make_executor as make

    return make(options)


@hookimpl
def register_executors(register: RegisterExecutor) -> None:
    register(NAME, make_executor)
