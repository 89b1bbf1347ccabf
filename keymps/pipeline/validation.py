"""`keymps validate`: everything a run checks before its first stage, without running it."""

from __future__ import annotations

from pathlib import Path

from keymps.errors import KeympsError, TaskFileError


def validate_task_file(path: Path) -> list[str]:
    """Problems with a task file, one line each (empty when the file is ready to run)."""
    from keymps.config.task import load_task

    try:
        task = load_task(path)
        from keymps.pipeline.engine import Components
        from keymps.planning.planner import choose_backend

        backend, _reason = choose_backend(task, None, None, None)
        Components(task, backend)
    except TaskFileError as error:
        return list(error.problems)
    except KeympsError as error:
        return [str(error)]
    return []
