"""The offline planner's sentence corpus (tests/data/instructions.yaml): every sentence reads as
its group expects, or is refused with the group's phrase in one line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from keymps.config.task import Task
from keymps.designs.grammar import read_instruction
from keymps.errors import KeympsError
from keymps.planning.family import check_sentence

CORPUS = Path(__file__).parents[1] / "data" / "instructions.yaml"
GROUPS: list[dict[str, Any]] = yaml.safe_load(CORPUS.read_text(encoding="utf-8"))
CASES = [(group, sentence) for group in GROUPS for sentence in group["sentences"]]
FAMILIES = {"straight": "cutting", "sawing": "cutting", "line": "icing"}


def test_the_corpus_is_large_and_covers_every_design() -> None:
    from keymps.designs.grammar import DESIGNS

    assert len(CASES) >= 300
    keys = [(g.get("tool"), s) for g, s in CASES]
    assert len(set(keys)) == len(keys), "a sentence is listed twice"
    expected = " ".join(g.get("expect", "") for g in GROUPS)
    for design in DESIGNS:
        assert f": {design.replace('_', ' ')}" in expected, design


def _reading(sentence: str) -> str:
    try:
        return read_instruction(sentence).describe()
    except KeympsError as error:
        message = str(error)
        assert "\n" not in message and message.strip()
        return f"refused: {message}"


@pytest.mark.parametrize(("group", "sentence"), CASES, ids=[s[:50] or "empty" for _, s in CASES])
def test_each_sentence_reads_as_expected(group: dict[str, Any], sentence: str) -> None:
    if "tool" in group:
        task = Task(
            name="family",
            instruction=sentence,
            scene={"source": "synthetic"},
            primitives=["straight", "sawing"] if group["tool"] == "knife" else ["line"],
            robot={"tool": group["tool"]},
        )
        families = {n: FAMILIES[n] for n in task.primitives}
        with pytest.raises(KeympsError, match=group["refuse"]):
            check_sentence(task, sentence, families)
        return
    reading = _reading(sentence)
    if "expect" in group:
        assert reading == group["expect"]
    else:
        assert reading.startswith("refused: ") and group["refuse"] in reading, reading


QUALIFIERS = [
    ("{}, but not near the edge", "not"),
    ("{} on the left half", "left half"),
    ("{}, of different sizes", "of different sizes"),
    ("{} except the crust", "except"),
    ("only the top half: {}", "top half"),
    ("{}, don't touch the candle", "don't"),
    ("{} without the corners", "without"),
]


def test_every_readable_sentence_with_a_word_no_design_models_is_refused() -> None:
    """Each sentence the corpus reads, with a negation, an exception, unequal parts or a part
    of the object added before or after it: refused naming that word, never read as the
    sentence without it (the design on the whole object is then a confident wrong motion)."""
    readable = [s for g, s in CASES if "expect" in g and "tool" not in g]
    assert len(readable) > 200
    for sentence in readable:
        for template, word in QUALIFIERS:
            reading = _reading(template.format(sentence))
            assert reading.startswith("refused: "), (template.format(sentence), reading)
            assert f"cannot follow {word!r}" in reading or "has no design" in reading, reading
