"""A plugin's options, validated by its pydantic model and reported as one line."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import AfterValidator, BaseModel, ValidationError

from keymps.errors import KeympsError

Options = TypeVar("Options", bound=BaseModel)


def _inside_the_run_folder(path: Path) -> Path:
    # A task file may come from a stranger: a plugin writes nothing outside the run folder,
    # and nothing over the run's own files in it
    if path.is_absolute() or ".." in path.parts or not path.name:
        raise ValueError(
            f"{str(path)!r} leads out of the run folder: name a file in it "
            "(--out chooses the folder)"
        )
    problem = run_file_clash(path)
    if problem:
        raise ValueError(problem)
    return path


def run_file_clash(path: Path) -> str | None:
    """Why a plugin may not write `path` (relative) in the run folder, None when it may: a
    control character in it, a file the run writes itself (keymps.run_files.RUN_OWN_FILES, compared
    case-folded), its vlm/ records, or a hidden name (the lock, the temporary files every file
    is written through)."""
    from keymps.run_files import RUN_OWN_FILES

    text = str(path)
    if any(ord(c) < 32 or ord(c) == 127 for c in text):
        return f"{text!r} holds a control character (a NUL or a newline): name a plain file"
    if path.parts[0].casefold() == "vlm":
        return f"{text!r} is inside vlm/, the run's VLM records: name another file"
    if any(part.startswith(".") for part in path.parts):
        return f"{text!r} is a hidden name, as the run's lock and temporary files are"
    if len(path.parts) == 1 and text.casefold() in {name.casefold() for name in RUN_OWN_FILES}:
        return f"{text!r} is one of the run's own files (docs/run-folder.md): name another file"
    return None


RunFolderPath = Annotated[Path, AfterValidator(_inside_the_run_folder)]
"""An option naming a file or folder inside the run folder (subfolders allowed): an absolute
path, one with `..` or a control character, a hidden name, vlm/ and the run's own files
(run.json, plan.png ...) are refused in one line. Write it with `run.path(str(option))`."""


def parse_options(model: type[Options], options: dict[str, Any] | None, component: str) -> Options:
    """Validate a plugin's options with its pydantic model.

    Args:
        model: The options' pydantic model (`extra="forbid"` makes unknown options errors).
        options: The task file's section for the plugin, without `name`; None for none.
        component: Names the plugin in the message, e.g. "threshold detector".

    Returns:
        The validated options.

    Raises:
        keymps.errors.KeympsError: One line naming every problem, e.g. "threshold detector:
            option 'blur': must be odd; option 'x': unknown option (options: ...)".
    """
    try:
        return model.model_validate(options or {})
    except ValidationError as error:
        problems = []
        for item in error.errors(include_url=False):
            key = ".".join(str(part) for part in item["loc"]) or "(options)"
            problems.append(f"option {key!r}: {_describe(model, key, item)}")
        known = ", ".join(f.alias or name for name, f in model.model_fields.items()) or "none"
        raise KeympsError(f"{component}: {'; '.join(problems)} (options: {known})") from None


def _describe(model: type[BaseModel], key: str, item: Any) -> str:
    if item["type"] == "extra_forbidden":
        return "unknown option"
    if item["type"] == "missing":
        field = model.model_fields.get(key)
        return f"required ({field.description})" if field and field.description else "required"
    return str(item["msg"]).removeprefix("Value error, ")
