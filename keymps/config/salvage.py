"""What `keymps validate` can still check in a task file that breaks the schema: the file with
every broken top-level field set aside."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import ValidationError

from keymps.config.task import (
    Task,
    TaskOrigin,
    display_path,
    read_task_text,
    referenced_file_problems,
)
from keymps.config.yaml_positions import YamlSyntaxError, load_yaml_with_positions
from keymps.errors import TaskFileError

_STAND_INS: dict[str, Any] = {
    "name": "stand-in",
    "instruction": "stand-in",
    "scene": {"image": "stand-in.png"},
    "primitives": ["line"],
}
"""Placeholders for required fields with a problem, so that the rest can still be checked."""


def salvage_task(path: str | Path) -> tuple[Task, frozenset[str], list[str]] | None:
    """For a task file with schema problems: the task with every top-level field that has one
    replaced (by its default or a stand-in), the names replaced, and the missing-file problems
    of the fields kept. `keymps validate` checks the rest of the file with it in the same run.
    None when the file cannot be read or parsed as YAML at all."""
    path = Path(path)
    try:
        parsed = load_yaml_with_positions(read_task_text(path))
    except (TaskFileError, YamlSyntaxError):
        return None
    if not isinstance(parsed.data, dict):
        return None
    data = {k: v for k, v in parsed.data.items() if k != "path"}
    try:
        Task.model_validate({**data, "path": path.resolve()})
        broken: set[str] = set()
    except ValidationError as error:
        # A bad key inside a section (scene.object_heigth) costs only that key, so that the
        # section's other fields (scene.image) are still checked in the same run; a section
        # still broken without its bad keys is set aside whole.
        data = _without_bad_keys(data, error)
        try:
            Task.model_validate({**data, "path": path.resolve()})
            broken = set()
        except ValidationError as still:
            broken = {str(e["loc"][0]) for e in still.errors() if e["loc"]}
    for key in broken:
        data.pop(key, None)
        if key in _STAND_INS:
            data[key] = _STAND_INS[key]
    try:
        task = Task.model_validate({**data, "path": path.resolve()})
    except ValidationError:
        return None
    source = display_path(path)
    task.remember_origin(TaskOrigin(source, parsed))
    problems = [
        problem
        for problem in referenced_file_problems(task, source, parsed)
        if problem.split(": ", 2)[1].split(".")[0] not in broken
    ]
    return task, frozenset(broken), problems


def _without_bad_keys(data: dict[str, Any], error: ValidationError) -> dict[str, Any]:
    """`data` without each key an error points at inside a section (two levels deep)."""
    pruned = dict(data)
    for item in error.errors():
        loc = item["loc"]
        if len(loc) < 2 or not isinstance(pruned.get(str(loc[0])), dict):
            continue
        section = dict(pruned[str(loc[0])])
        section.pop(str(loc[1]), None)
        pruned[str(loc[0])] = section
    return pruned
