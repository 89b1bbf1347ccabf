"""A plan's intent as data: from the offline grammar's reading, a named design, or the `intent`
field of a VLM answer (keymps.types.PlanIntent; docs/outcome.md).

The grammar (keymps.designs.grammar.Intent) says which design a sentence asks for; this module
says what that design must leave on the object: how many pieces and whether equal, which
direction the cuts run in the object's own frame, how many dots or rings.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from keymps.designs.grammar import Intent
from keymps.types import EQUAL_PARTS_TOLERANCE, IntentSource, PlanIntent

ORIENTATIONS = ("vertical", "horizontal", "lengthwise", "crosswise")


def intent_of_design(design: Intent, source: IntentSource = "offline") -> PlanIntent:
    """What the grammar's design `design` claims to leave on the object."""
    claim = PlanIntent(family=design.family, design=design.design, source=source)
    count = design.count
    if design.design == "equal" and count is not None:
        return replace(
            claim,
            pieces=count,
            equal=EQUAL_PARTS_TOLERANCE,
            orientation=design.orientation,
        )
    if design.design == "parallel" and count is not None:
        # equal spacing across the cuts (the eval's ground truth for "N parts vertically")
        return replace(
            claim,
            pieces=count,
            equal=EQUAL_PARTS_TOLERANCE,
            equal_by="width",
            orientation=design.orientation,
        )
    if design.design == "width":
        return replace(
            claim,
            slice_width_mm=design.slice_width_mm,
            object_length_mm=design.object_length_mm,
            orientation=design.orientation,
        )
    if design.design == "middle":
        return replace(claim, pieces=2, orientation=design.orientation)
    if design.design == "tips":
        return replace(claim, pieces=3)
    return _icing(claim, design)


def _icing(claim: PlanIntent, design: Intent) -> PlanIntent:
    count = design.count
    if design.design == "dot":
        return replace(claim, dots=1)
    if design.design == "dots_ring" and count is not None:
        return replace(claim, dots=count * (design.layers or 1))
    if design.design in ("dots_spiral", "dot_per_slice") and count is not None:
        return replace(claim, dots=count)
    if design.design == "rings":
        return replace(claim, rings=count or 1)
    if design.design == "digits":
        return replace(claim, digits=design.text)
    return claim


class IntentAnswer(BaseModel):
    """The optional `intent` field of an answer: what the pairs are meant to achieve."""

    model_config = ConfigDict(extra="forbid")
    pieces: int | None = Field(default=None, strict=True, ge=1, le=1000)
    equal: bool | None = None
    orientation: str | None = None
    slice_width_cm: float | None = Field(default=None, gt=0, le=1000, allow_inf_nan=False)
    dots: int | None = Field(default=None, strict=True, ge=0, le=1000)
    rings: int | None = Field(default=None, strict=True, ge=0, le=100)


INTENT_FIELDS = {
    "pieces": ("integer", "how many pieces your cuts leave on the object"),
    "equal": ("boolean", "true when the pieces are meant to be equal"),
    "orientation": ("string", "the cuts' direction relative to the object's own sides"),
    "slice_width_cm": ("number", "each slice's width in cm, when the request gives one"),
    "dots": ("integer", "how many icing dots in all"),
    "rings": ("integer", "how many closed icing lines (rings) around the object"),
}


def intent_schema() -> dict[str, Any]:
    """The JSON schema of an answer's `intent` (OpenAI strict: every field present, maybe null)."""
    properties: dict[str, Any] = {
        name: {"type": [kind, "null"], "description": description}
        for name, (kind, description) in INTENT_FIELDS.items()
    }
    properties["orientation"]["enum"] = [*ORIENTATIONS, None]
    return {
        "anyOf": [
            {
                "type": "object",
                "description": "what your pairs achieve, checked against the predicted result "
                "before the robot moves; null fields state nothing",
                "properties": properties,
                "required": list(properties),
                "additionalProperties": False,
            },
            {"type": "null"},
        ]
    }


def intent_of_answer(answer: IntentAnswer, family: str) -> tuple[PlanIntent | None, list[str]]:
    """(the PlanIntent, []) or (None, the problems in words a model can act on)."""
    if answer.orientation is not None and answer.orientation not in ORIENTATIONS:
        return None, [f"intent.orientation must be one of {', '.join(ORIENTATIONS)}, or null"]
    cutting = family != "icing"
    stated = PlanIntent(
        family="cut" if cutting else "icing",
        pieces=answer.pieces if cutting else None,
        equal=EQUAL_PARTS_TOLERANCE if cutting and answer.equal else None,
        orientation=answer.orientation if cutting else None,  # type: ignore[arg-type]
        slice_width_mm=10 * answer.slice_width_cm if cutting and answer.slice_width_cm else None,
        dots=None if cutting else answer.dots,
        rings=None if cutting else answer.rings,
        source="answer",
    )
    if stated.equal is not None and stated.pieces is None:
        return None, ["intent.equal needs intent.pieces: how many equal pieces"]
    return stated, []
