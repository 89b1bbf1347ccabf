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
    """Read and validate a task file.

    Args:
        path: The task file (str or Path); paths inside it are relative to its folder.

    Returns:
        The validated Task (`task.path` is the file, `task.where(...)` locates a field).

    Raises:
        keymps.errors.TaskFileError: One `file:line:col: field: message` line per problem
            (unknown keys, wrong types, files it names that cannot be read ...).
    """
    from keymps.config.task import load_task as _load_task

    return _load_task(path)


def run_task(task: Task | Any, **overrides: Any) -> Run:
    """Run a task end to end: image, detect, plan, ground, compose, solve, time, check, execute.

    Every component is built before the first stage, so a configuration error costs nothing.
    The run folder (run.json, trajectory.csv, plan.png, run.rrd ...) is written even when a
    stage fails.

    Args:
        task: A Task, or the path of a task file (loaded with `load_task`).
        **overrides: What the command line can change: instruction, image, backend, model,
            api_base, executor, out (the run folder), rerun (save, spawn, connect, off),
            rerun_url, no_cache, record (a cassette path), confirm (real-robot executors move
            only with it), quiet, image_format (png, jpg); `through="ground"` stops after
            grounding.

    Returns:
        The finished Run: `run.folder`, and each stage's typed result in `run.stages`
        (`run.stages.plan.keyword`, `run.stages.time.duration_s` ...).

    Raises:
        keymps.errors.KeympsError: On the first problem, as one line; a failed stage raises
            StageError naming it ("detect: no object found"), and nothing after it runs, above
            all no executor. `error.run` is the Run it leaves behind.
    """
    from keymps.pipeline.engine import run_task as _run_task

    return _run_task(task, **overrides)
