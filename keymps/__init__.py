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

__all__ = [
    "KeympsError",
    "Run",
    "RunOptions",
    "RunOverrides",
    "Task",
    "__version__",
    "hookimpl",
    "load_task",
    "run_task",
]

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.pipeline.engine import StageCallback
    from keymps.plugin.hookspecs import hookimpl
    from keymps.run import Run, RunOptions, RunOverrides

_LAZY = {
    "Task": "keymps.config.task",
    "Run": "keymps.run",
    "RunOptions": "keymps.run",
    "RunOverrides": "keymps.run",
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


def run_task(
    task: Task | Any,
    *,
    on_stage: StageCallback | None = None,
    options: RunOptions | None = None,
    overrides: RunOverrides | None = None,
    through: str = "execute",
    **keywords: Any,
) -> Run:
    """Run a task end to end: image, detect, plan, ground, compose, solve, time, check, execute.

    Every component is built before the first stage, so a configuration error costs nothing.
    The run folder (run.json, trajectory.csv, plan.png, run.rrd ...) is written even when a
    stage fails.

    ```python
    from pathlib import Path

    from keymps import RunOptions, RunOverrides, run_task

    run = run_task(
        "tasks/cake_8_slices.yaml",
        options=RunOptions(rerun="off", quiet=True),
        overrides=RunOverrides(backend="offline", executor="sim", out=Path("runs/cake")),
    )
    ```

    Args:
        task: A Task, or the path of a task file (loaded with `load_task`).
        on_stage: Called as `on_stage(stage, seconds, result)` after each stage.
        options: How the run is carried out (keymps.RunOptions: Rerun recording, answer
            cache, cassette recording, `confirm` for real robots, image format ...).
        overrides: What the run changes of the task file (keymps.RunOverrides: instruction,
            image, backend, model, api_base, cassette, answer, executor, out).
        through: "execute" (every stage) or "ground" (stop after grounding the plan: nothing
            is timed, checked or executed).
        **keywords: Deprecated: the fields of RunOptions and RunOverrides by name (a
            DeprecationWarning; removed in a later release).

    Returns:
        The finished Run: `run.folder`, and each stage's typed result in `run.stages`
        (`run.stages.plan.keyword`, `run.stages.time.duration_s` ...).

    Raises:
        keymps.errors.KeympsError: On the first problem, as one line; a failed stage raises
            StageError naming it ("detect: no object found"), and nothing after it runs, above
            all no executor. `error.run` is the Run it leaves behind.
    """
    from keymps.pipeline.engine import apply_deprecated_keywords
    from keymps.pipeline.engine import run_task as _run_task
    from keymps.run import RunOptions, RunOverrides

    # the deprecated keywords converted here, so that their warning names the caller's line
    options, overrides = apply_deprecated_keywords(
        options or RunOptions(), overrides or RunOverrides(), keywords
    )
    return _run_task(task, on_stage=on_stage, options=options, overrides=overrides, through=through)
