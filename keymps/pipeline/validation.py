"""`keymps validate`: everything a run checks before its first stage, without running it.

Every independent problem of a file is reported in one run: schema problems first, then, with
the fields that have one set aside, missing files, component options (image source, detector,
executor), primitives, the prompt template and the robot model.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

from keymps.errors import KeympsError, TaskFileError
from keymps.planning.backend_choice import NO_SERVER

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.pipeline.engine import Components


def validate_task_file(path: Path, notes: list[str] | None = None) -> list[str]:
    """Problems with a task file, one line each (empty when the file is ready to run); what a
    run would warn about is appended to `notes` (e.g. that no key goes to its api_base)."""
    from keymps.config.salvage import salvage_task
    from keymps.config.task import load_task

    try:
        task = load_task(path)
    except TaskFileError as error:
        problems = list(error.problems)
        salvaged = salvage_task(path)
        if salvaged is None:
            return problems
        task, broken, missing = salvaged
        if any(": planner.prompt: " in line for line in missing):
            broken |= {"planner"}  # the prompt check would say it again
        problems += [*missing, *component_problems(task, broken)]
        return sorted(dict.fromkeys(problems), key=_line_and_column)
    except KeympsError as error:
        return [str(error)]
    return sorted(component_problems(task, notes=notes), key=_line_and_column)


def component_problems(
    task: Task, skip: frozenset[str] = frozenset(), notes: list[str] | None = None
) -> list[str]:
    """What building the run's components finds, leaving out the task fields in `skip`."""
    from keymps.pipeline.engine import Components
    from keymps.planning.backend_choice import untrusted_api_base_warning
    from keymps.planning.planner import choose_backend
    from keymps.planning.sent_files import files_refused

    problems: list[str] = []
    parts: Components | None = None
    backend = None
    try:
        backend, _reason = choose_backend(task, None, None, None)
        parts = Components(task, backend, skip=skip)
    except TaskFileError as error:
        problems += error.problems
    except KeympsError as error:
        problems.append(str(error))
    if not {"planner", "primitives"} & skip:
        descriptions = _descriptions(task, parts)
        if descriptions is not None:
            try:
                _check_prompt(task, descriptions)
                if backend is not None and backend not in NO_SERVER:
                    problems += files_refused(task, descriptions)
            except KeympsError as error:
                problems.append(str(error))
    if parts is not None and notes is not None and backend not in NO_SERVER:
        keyless = untrusted_api_base_warning(task)
        if keyless:
            notes.append(keyless)
    return problems


def _descriptions(task: Task, parts: Components | None) -> dict[str, str] | None:
    """Primitive name -> description, from the built parts or, when those failed, loaded
    again; None when the primitives themselves are the problem."""
    from keymps.primitives.dictionary import default_search_dirs, load_primitives

    primitives = parts.primitives if parts is not None else None
    if primitives is None:
        try:
            primitives = load_primitives(task.primitives, default_search_dirs(task.folder))
        except KeympsError:
            return None
    return {name: p.description for name, p in primitives.items()}


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


_LOCATION = re.compile(r":(\d+):(\d+): ")


def _line_and_column(problem: str) -> tuple[int, int]:
    """Where in the file a problem is (problems without a place come last)."""
    found = _LOCATION.search(problem)
    return (int(found.group(1)), int(found.group(2))) if found else (1 << 30, 0)
