"""A plan's intent as data: the grammar's designs, named designs and VLM answers mapped to one
typed form (keymps.planning.intent)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from keymps.designs.grammar import DESIGNS, Intent, UnreadableInstruction, read_instruction
from keymps.errors import KeympsError
from keymps.planning.intent import IntentAnswer, intent_of_answer, intent_of_design
from keymps.types import EQUAL_PARTS_TOLERANCE, PlanIntent

CORPUS = Path(__file__).resolve().parents[1] / "data" / "instructions.yaml"


def _corpus_sentences() -> list[str]:
    groups = yaml.safe_load(CORPUS.read_text())
    return [s for group in groups if "expect" in group for s in group["sentences"]]


def test_every_sentence_the_grammar_reads_states_what_it_leaves() -> None:
    """Every design of the corpus maps to an intent of its family; the cut designs that fix the
    pieces say how many, and equal parts say equal within Appendix F's 5 %."""
    read = 0
    for sentence in _corpus_sentences():
        try:
            design = read_instruction(sentence)
        except (UnreadableInstruction, KeympsError):
            continue
        read += 1
        claim = intent_of_design(design)
        assert claim.family == design.family and claim.design == design.design
        assert claim.source == "offline"
        if design.design in ("equal", "parallel"):
            assert claim.pieces == design.count and claim.equal == EQUAL_PARTS_TOLERANCE
            assert claim.orientation == design.orientation
        if design.design == "dots_ring" and design.count:
            assert claim.dots == design.count * (design.layers or 1)
        assert claim.describe()
    assert read >= 80


@pytest.mark.parametrize(
    ("design", "expected"),
    [
        (Intent("cut", "parallel", count=3, orientation="vertical"),
         "3 pieces, equal within 5 %, cut vertically"),
        (Intent("cut", "equal", count=6), "6 pieces, equal within 5 %"),
        (Intent("cut", "width", slice_width_mm=50, object_length_mm=200),
         "slices 5 cm wide, of an object 20 cm long"),
        (Intent("cut", "middle", count=1, orientation="horizontal"),
         "2 pieces, cut horizontally"),
        (Intent("cut", "tips"), "3 pieces"),
        (Intent("icing", "dots_ring", count=12, layers=2), "24 dots"),
        (Intent("icing", "rings", count=2), "2 rings"),
        (Intent("icing", "digits", text="27"), "the digits '27'"),
        (Intent("icing", "spiral"), "spiral"),
    ],
)  # fmt: skip
def test_designs_read_as_what_they_leave(design: Intent, expected: str) -> None:
    assert intent_of_design(design).describe() == expected


def test_every_design_of_the_catalogue_maps() -> None:
    for name in DESIGNS:
        family = "cut" if name in ("equal", "parallel", "width", "middle", "tips") else "icing"
        claim = intent_of_design(Intent(family, name, count=4), source="design")  # type: ignore[arg-type]
        assert isinstance(claim, PlanIntent) and claim.source == "design"


def test_an_answers_intent_is_read_for_its_family_and_checked() -> None:
    cut, problems = intent_of_answer(
        IntentAnswer(pieces=6, equal=True, orientation="vertical"), "cutting"
    )
    assert problems == [] and cut is not None
    assert (cut.pieces, cut.equal, cut.orientation, cut.source) == (6, 0.05, "vertical", "answer")
    icing, _ = intent_of_answer(IntentAnswer(dots=15, pieces=3), "icing")
    assert icing is not None and (icing.dots, icing.pieces) == (15, None)
    bad, problems = intent_of_answer(IntentAnswer(orientation="diagonal"), "cutting")
    assert bad is None and "intent.orientation must be one of" in problems[0]
    bad, problems = intent_of_answer(IntentAnswer(equal=True), "cutting")
    assert bad is None and "intent.equal needs intent.pieces" in problems[0]
