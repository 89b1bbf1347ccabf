"""Which of the user's files a run would send to a server the user did not name.

A server only a task file chose (its planner.api_base, and nothing of the user's names it)
gets no key (keymps.planning.backend_choice), and no file that could be one of the user's:

- no scene image from outside the task file's folder tree, links followed, or from a hidden
  folder in it;
- no scene image and no prompt template with a second name (a hard link): a path check
  cannot tell which of its names the task's copy is, and the other may be `~/.ssh/id_rsa`.

The user lifts either by naming the file (--image) or the server (--api-base,
trusted_api_bases). Prompts in the user's own folders ($KEYMPS_PROMPTS_PATH, the bundled
ones) are the user's and not checked (an installer may hard-link those).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from keymps.config.trust import real_path, shown_path, user_prompt_dirs
from keymps.config.user import config_path
from keymps.planning.backend_choice import api_base_trusted, untrusted_server
from keymps.planning.redaction import redact_text

if TYPE_CHECKING:
    from keymps.config.task import Task


def files_refused(
    task: Task, primitives: Mapping[str, str], image_given: bool = False
) -> list[str]:
    """One located line per file the run would send a server only the task file names.

    Args:
        task: the task, after command-line overrides.
        primitives: the task's primitives, name -> description (they choose the prompt).
        image_given: the image came from --image (the user's choice).

    Returns:
        The refusals, empty when the server is the user's or nothing is refused.

    Raises:
        KeympsError: there is no prompt template the run could read.
    """
    from keymps.planning.prompt import prompt_family

    if api_base_trusted(task):
        return []
    refused = [] if image_given else _image_refused(task)
    return refused + _prompt_refused(task, prompt_family(primitives))


def _image_refused(task: Task) -> list[str]:
    image = task.scene.image
    if task.scene.source != "file" or image is None:
        return []
    where = f"{task.where('scene', 'image')}: scene.image {shown_path(image)}"
    folder = real_path(task.folder)
    real = real_path(task.resolve(image))
    if not real.is_relative_to(folder):  # (an absolute image stays)
        return [_line(task, f"{where} is outside the task file's folder", "pass it with --image")]
    hidden = next((p for p in real.relative_to(folder).parts if p.startswith(".")), None)
    if hidden is not None:
        return [_line(task, f"{where} is in the hidden folder {hidden!r}", "pass it with --image")]
    names = _names(real)
    if names > 1:
        return [_line(task, f"{where} {_hard_link(names)}", "pass it with --image")]
    return []


def _prompt_refused(task: Task, family: str) -> list[str]:
    from keymps.planning.prompt import find_prompt

    explicit = task.resolve(task.planner.prompt) if task.planner.prompt else None
    where = f"{task.where('planner', 'prompt')}: planner.prompt"
    found = real_path(find_prompt(explicit, task.folder, family, where))
    if any(found.is_relative_to(folder) for folder in user_prompt_dirs()):
        return []
    names = _names(found)
    if names <= 1:
        return []
    if explicit is None:
        where = f"{task.where('primitives')}: prompt template {family}.md ({found})"
    else:
        where = f"{where} {shown_path(task.planner.prompt or explicit)}"
    return [
        _line(task, f"{where} {_hard_link(names)}", "put it in a folder of $KEYMPS_PROMPTS_PATH")
    ]


def _names(path: Path) -> int:
    """How many names (hard links) the file has; 1 when it cannot be read (reported elsewhere)."""
    try:
        return os.stat(path).st_nlink
    except OSError:
        return 1


def _hard_link(names: int) -> str:
    return (
        f"is a hard link (one of {names} names of the same file, the others anywhere on this "
        "disk, which a path check cannot see)"
    )


def _line(task: Task, what: str, own_choice: str) -> str:
    """The refusal: what is refused, and the user's ways to lift it."""
    return redact_text(
        f"{what}, and {untrusted_server(task)}: keymps sends none of your files to a server "
        f"only a task file names; copy the file so that it has one name inside the task's "
        f"folder, {own_choice}, or pass the server with --api-base, or list it under "
        f"trusted_api_bases in {config_path()}"
    )
