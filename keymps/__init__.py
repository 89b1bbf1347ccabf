"""keymps: one image and one sentence to a safe, timed robot trajectory (KeyMPs).

The public API. Names are imported on first use, so `import keymps` (and `keymps --help`)
stays fast.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from keymps import _decoder_limit
from keymps._version import __version__
from keymps.errors import KeympsError

_decoder_limit.install()  # before anything imports cv2: decode bombs are refused from headers

__all__ = ["KeympsError", "Run", "Task", "__version__", "hookimpl", "load_task", "run_task"]

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.plugin.hookspecs import hookimpl
    from keymps.run import Run

_LAZY = {
    "Task": "keymps.config.task",
    "Run": "keymps.run",
    "hookimpl": "keymps.plugin.hookspecs",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'keymps' has no attribute {name!r}")


def load_task(path: Any) -> Task:
    """Read and validate a task file (errors carry file:line:col)."""
    from keymps.config.task import load_task as _load_task

    return _load_task(path)


def run_task(task: Task | Any, **overrides: Any) -> Run:
    """Run a task (a Task or a path to one) end to end and return the finished Run."""
    from keymps.pipeline.engine import run_task as _run_task

    return _run_task(task, **overrides)
