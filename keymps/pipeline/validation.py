"""`keymps validate`: everything a run checks before its first stage, without running it."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from keymps.errors import KeympsError, TaskFileError

if TYPE_CHECKING:
    from keymps.config.task import Task


def validate_task_file(path: Path, notes: list[str] | None = None) -> list[str]:
    """Problems with a task file, one line each (empty when the file is ready to run); what a
    run would warn about is appended to `notes` (e.g. that no key goes to its api_base)."""
    from keymps.config.task import load_task

    try:
        task = load_task(path)
        from keymps.pipeline.engine import Components
        from keymps.planning.backend_choice import untrusted_api_base_warning
        from keymps.planning.planner import choose_backend

        backend, _reason = choose_backend(task, None, None, None)
        parts = Components(task, backend)
        _check_prompt(task, {name: p.description for name, p in parts.primitives.items()})
        keyless = untrusted_api_base_warning(task) if backend not in ("offline", "replay") else None
        if keyless and notes is not None:
            notes.append(keyless)
    except TaskFileError as error:
        return list(error.problems)
    except KeympsError as error:
        return [str(error)]
    return []


def _check_prompt(task: Task, primitives: dict[str, str]) -> None:
    """The prompt template a run would read: found, a small regular file, in an allowed folder."""
    from keymps.planning.prompt import find_prompt, prompt_family

    planner = task.planner
    find_prompt(
        task.resolve(planner.prompt) if planner.prompt else None,
        task.folder,
        prompt_family(primitives),
        where=f"{task.where('planner', 'prompt')}: planner.prompt",
    )
