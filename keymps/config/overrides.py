"""Command-line overrides of a task (--instruction, --image, --backend ...), re-validated."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from keymps.config.task import Task, file_problem, image_file_problem
from keymps.errors import KeympsError

_OVERRIDE_FIELDS: dict[str, tuple[str, ...]] = {
    "instruction": ("instruction",),
    "image": ("scene", "image"),
    "backend": ("planner", "backend"),
    "model": ("planner", "model"),
    "api_base": ("planner", "api_base"),
    "cassette": ("planner", "cassette"),
    "answer": ("planner", "answer"),
    "executor": ("executor", "name"),
}


def apply_overrides(task: Task, overrides: dict[str, Any]) -> Task:
    """A copy of `task` with the given overrides applied and validated (None means unchanged)."""
    unknown = sorted(set(overrides) - set(_OVERRIDE_FIELDS))
    if unknown:
        raise KeympsError(f"unknown run option(s): {', '.join(unknown)}")
    given = {k: v for k, v in overrides.items() if v is not None}
    if not given:
        return task
    data = task.model_dump(mode="python")
    for key, value in given.items():
        *parents, leaf = _OVERRIDE_FIELDS[key]
        target = data
        for parent in parents:
            target = target[parent]
        if key in ("image", "cassette"):
            value = Path(os.path.abspath(value))  # resolve() raises on a symlink loop
            if key == "image":
                problem = file_problem(value) or image_file_problem(value)
                if problem:
                    raise KeympsError(f"--image: {problem}")
                data["scene"]["source"] = "file"
        target[leaf] = value
    data["path"] = task.path
    try:
        updated = Task.model_validate(data)
    except ValidationError as error:
        first = error.errors(include_url=False)[0]
        field = ".".join(str(p) for p in first["loc"])
        message = str(first["msg"]).removeprefix("Value error, ")
        raise KeympsError(f"override {field}: {message}") from None
    origin = task.origin
    if "api_base" in given:
        # an api_base given here is the user's own: the one the file wrote no longer applies
        origin = replace(origin, api_base=None)
    return updated.remember_origin(origin)
