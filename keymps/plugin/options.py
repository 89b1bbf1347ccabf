"""A plugin's options, validated by its pydantic model and reported as one line."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import AfterValidator, BaseModel, ValidationError

from keymps.errors import KeympsError

Options = TypeVar("Options", bound=BaseModel)


def _inside_the_run_folder(path: Path) -> Path:
    # A task file may come from a stranger: a plugin writes nothing outside the run folder.
    if path.is_absolute() or ".." in path.parts or not path.name:
        raise ValueError(
            f"{str(path)!r} leads out of the run folder: name a file in it "
            "(--out chooses the folder)"
        )
    return path


RunFolderPath = Annotated[Path, AfterValidator(_inside_the_run_folder)]
"""An option naming a file or folder inside the run folder (subfolders allowed): an absolute
path or one with `..` is refused in one line. Write it with `run.path(str(option))`."""


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
