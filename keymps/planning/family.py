"""Tool families: a plan's primitive family must fit the task's tool, for every backend.

A knife cuts and a piping bag ices. A sentence that asks for the other family ("Put 10 icing
dots around the bread" on a knife task) stops before any model is asked, and a plan whose
primitive belongs to the other family (a VLM choosing `line` for a knife) stops after it: both
at the plan stage, with one line naming the two families.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import TYPE_CHECKING

from keymps.errors import KeympsError

if TYPE_CHECKING:
    from keymps.config.task import Task

TOOL_FAMILIES = {"knife": "cutting", "piping_bag": "icing"}
"""Built-in tool -> the primitive family it serves."""
_ICING_TEXT = re.compile(r"icing|pip(e|ing)|frost|decorat|rosette|nozzle", re.IGNORECASE)
_SENTENCE_FAMILY = {"cut": "cutting", "icing": "icing"}


def families_from_descriptions(primitives: Mapping[str, str]) -> dict[str, str]:
    """name -> family read from the descriptions (when the primitive files are not at hand)."""
    return {
        name: "icing" if _ICING_TEXT.search(f"{name} {text}") else "cutting"
        for name, text in primitives.items()
    }


def tool_family(task: Task, families: Mapping[str, str]) -> tuple[str | None, str]:
    """(family, what decided it): the task's built-in tool, else its primitives' one family."""
    tool = task.robot.tool.name
    if "tool" in task.robot.model_fields_set and tool in TOOL_FAMILIES:
        return TOOL_FAMILIES[tool], f"the task's tool is {tool}"
    kinds = sorted(set(families.values()))
    if len(kinds) == 1:
        return kinds[0], f"the task's primitives ({', '.join(families)}) are all {kinds[0]}"
    return None, "the task's primitives mix families"


def _fit(family: str, families: Mapping[str, str]) -> str:
    names = [n for n, f in families.items() if f == family]
    return ", ".join(names) if names else "none in this task"


def _a(word: str) -> str:
    return f"an {word}" if word[0] in "aeiou" else f"a {word}"


def check_sentence(task: Task, instruction: str, families: Mapping[str, str]) -> None:
    """Refuse a sentence that clearly asks for the family the task's tool does not serve."""
    from keymps.designs.grammar import sentence_family

    asked = sentence_family(instruction)
    wanted, why = tool_family(task, families)
    if asked is None or wanted is None or _SENTENCE_FAMILY[asked] == wanted:
        return
    asked_family = _SENTENCE_FAMILY[asked]
    raise KeympsError(
        f"the sentence {instruction.strip()[:80]!r} asks for {asked_family}, but {why} "
        f"({wanted}; {asked_family} primitives: {_fit(asked_family, families)}): use "
        f"{_a(asked_family)} task (tool and primitives) or {_a(wanted)} sentence"
    )


def check_plan(task: Task, keyword: str, families: Mapping[str, str]) -> None:
    """Refuse a plan whose primitive's family does not fit the task's tool."""
    wanted, why = tool_family(task, families)
    family = families.get(keyword)
    if wanted is None or family is None or family == wanted:
        return
    raise KeympsError(
        f"the plan uses primitive {keyword!r} ({family}), but {why} ({wanted}; {wanted} "
        f"primitives: {_fit(wanted, families)}); nothing is executed"
    )
