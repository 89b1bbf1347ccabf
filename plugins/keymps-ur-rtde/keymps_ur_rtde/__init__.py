"""keymps-ur-rtde: run keymps trajectories on a real Universal Robots arm (ur_rtde)."""

from __future__ import annotations

from keymps.plugin import RegisterExecutor, hookimpl

__version__ = "0.1.0"


@hookimpl
def register_executors(register: RegisterExecutor) -> None:
    from keymps_ur_rtde.executor import NAME, make_executor

    register(NAME, make_executor)
