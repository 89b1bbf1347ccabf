"""keymps: one image and one sentence to a safe, timed robot trajectory (KeyMPs)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"
__all__ = ["__version__", "load_task", "run_task"]

if TYPE_CHECKING:
    from keymps.run import Run
    from keymps.task import Task


def load_task(path: Any) -> Task:
    """Read and validate a task file (errors carry file:line:col)."""
    from keymps.task import load_task as _load_task

    return _load_task(path)


def run_task(task: Task | Any, **overrides: Any) -> Run:
    """Run a task (a Task or a path to one) end to end and return the finished Run."""
    from keymps.engine import run_task as _run_task

    return _run_task(task, **overrides)
