"""A plan's intent as data: from the offline grammar's reading, a named design, or the `intent`
field of a VLM answer (keymps.types.PlanIntent; docs/outcome.md).

The grammar (keymps.designs.grammar.Intent) says which design a sentence asks for; this module
says what that design must leave on the object: how many pieces and whether equal, which
direction the cuts run in the object's own frame, how many dots or rings.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field

from keymps.designs.grammar import Intent, read_instruction
from keymps.errors import KeympsError
from keymps.types import EQUAL_PARTS_TOLERANCE, IntentSource, PieceShape, PlanIntent

ORIENTATIONS = ("vertical", "horizontal", "lengthwise", "crosswise")


def intent_of_design(design: Intent, source: IntentSource = "offline") -> PlanIntent:
    """What the grammar's design `design` claims to leave on the object."""
    claim = PlanIntent(
        family=design.family,
        design=design.design,
        piece_shape=design.piece_shape,
        edge_distance_mm=design.edge_distance_mm,
        source=source,
    )
    count = design.count
    if design.design == "equal" and count is not None:
        return replace(
            claim,
            pieces=count,
            equal=EQUAL_PARTS_TOLERANCE,
            orientation=design.orientation,
        )
    if design.design == "parallel" and count is not None:
        # equal widths on a round or long object, areas on a square (keymps.outcome.verdict)
        return replace(
            claim, pieces=count, equal=EQUAL_PARTS_TOLERANCE, orientation=design.orientation
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


CHECKED_DESIGNS = ("middle", "parallel")
"""The designs whose name the outcome checks read (keymps.outcome.verdict)."""


def sentence_intent(instruction: str) -> PlanIntent | None:
    """What the instruction itself asks, as the offline grammar reads it (source "sentence"):
    what a VLM's plan is held to besides its own claim. None where the grammar does not read
    the sentence (it never guesses). The design is kept only where the checks read it
    ("middle": the cut's place; "parallel": a round object's slices compare widths): how a
    VLM lays out what was asked is its own."""
    try:
        read = read_instruction(instruction)
    except KeympsError:  # unreadable, or numbers it does not model: no reading to hold to
        return None
    asked = intent_of_design(read, source="sentence")
    return replace(asked, design=asked.design if asked.design in CHECKED_DESIGNS else None)


class IntentAnswer(BaseModel):
    """The optional `intent` field of an answer: what the pairs are meant to achieve.

    A VLM's schema asks for the fields of INTENT_FIELDS; the offline planner also states the
    design, what equal parts compare and the object's stated length (answer_of_intent); an
    answer may state them too."""

    model_config = ConfigDict(extra="forbid")
    pieces: int | None = Field(default=None, strict=True, ge=1, le=1000)
    equal: bool | None = None
    orientation: str | None = None
    slice_width_cm: float | None = Field(default=None, gt=0, le=1000, allow_inf_nan=False)
    dots: int | None = Field(default=None, strict=True, ge=0, le=1000)
    rings: int | None = Field(default=None, strict=True, ge=0, le=100)
    digits: str | None = Field(default=None, pattern=r"^[0-9]{1,12}$")
    object: int | None = Field(default=None, strict=True)
    """With several objects: the id of the object it is for."""
    equal_by: Literal["area", "width"] | None = None
    object_length_cm: float | None = Field(default=None, gt=0, le=1000, allow_inf_nan=False)
    design: str | None = Field(default=None, max_length=40)
    piece_shape: PieceShape | None = None
    edge_distance_cm: float | None = Field(default=None, gt=0, le=1000, allow_inf_nan=False)
    """Icing: the outer ring's distance in from the object's edge, cm."""


INTENT_FIELDS = {
    "pieces": ("integer", "how many pieces your cuts leave on the object"),
    "equal": ("boolean", "true when the pieces are meant to be equal"),
    "orientation": ("string", "the cuts' direction relative to the object's own sides"),
    "slice_width_cm": ("number", "each slice's width in cm, when the request gives one"),
    "dots": ("integer", "how many icing dots in all"),
    "rings": ("integer", "how many closed icing lines (rings) around the object"),
    "digits": ("string", "the digits drawn, when the request asks for digits"),
    "piece_shape": ("string", "the pieces' shape, when the request names one"),
    "edge_distance_cm": ("number", "icing: the outer ring's distance in from the edge, in cm"),
}


def intent_schema() -> dict[str, Any]:
    """The JSON schema of an answer's `intent` (OpenAI strict: every field present, maybe null)."""
    properties: dict[str, Any] = {
        name: {"type": [kind, "null"], "description": description}
        for name, (kind, description) in INTENT_FIELDS.items()
    }
    properties["orientation"]["enum"] = [*ORIENTATIONS, None]
    properties["piece_shape"]["enum"] = [*get_args(PieceShape), None]
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


def intent_of_answer(
    answer: IntentAnswer, family: str, source: IntentSource = "answer"
) -> tuple[PlanIntent | None, list[str]]:
    """(the PlanIntent, []) or (None, the problems in words a model can act on)."""
    if answer.orientation is not None and answer.orientation not in ORIENTATIONS:
        return None, [f"intent.orientation must be one of {', '.join(ORIENTATIONS)}, or null"]
    cutting = family != "icing"
    if not cutting:
        return PlanIntent(
            family="icing",
            design=answer.design,
            dots=answer.dots,
            rings=answer.rings,
            digits=answer.digits,
            edge_distance_mm=10 * answer.edge_distance_cm if answer.edge_distance_cm else None,
            object_id=answer.object,
            source=source,
        ), []
    if answer.equal and answer.pieces is None:
        return None, ["intent.equal needs intent.pieces: how many equal pieces"]
    return PlanIntent(
        family="cut",
        design=answer.design,
        pieces=answer.pieces,
        equal=EQUAL_PARTS_TOLERANCE if answer.equal else None,
        equal_by=answer.equal_by if answer.equal else None,
        orientation=answer.orientation,  # type: ignore[arg-type]
        piece_shape=answer.piece_shape,
        slice_width_mm=10 * answer.slice_width_cm if answer.slice_width_cm else None,
        object_length_mm=10 * answer.object_length_cm if answer.object_length_cm else None,
        object_id=answer.object,
        source=source,
    ), []


def answer_of_intent(intent: PlanIntent) -> dict[str, Any]:
    """The `intent` answer field that states `intent` (the inverse of intent_of_answer)."""
    stated = {
        "pieces": intent.pieces,
        "equal": True if intent.equal is not None else None,
        "orientation": intent.orientation,
        "slice_width_cm": intent.slice_width_mm / 10 if intent.slice_width_mm else None,
        "dots": intent.dots,
        "rings": intent.rings,
        "digits": intent.digits,
        "object": intent.object_id,
        "equal_by": intent.equal_by,
        "object_length_cm": intent.object_length_mm / 10 if intent.object_length_mm else None,
        "design": intent.design,
        "piece_shape": intent.piece_shape,
        "edge_distance_cm": intent.edge_distance_mm / 10 if intent.edge_distance_mm else None,
    }
    return {name: value for name, value in stated.items() if value is not None}


def plan_intents(answer: Any, family: str, asks_model: bool) -> tuple[PlanIntent, ...]:
    """What a valid answer claims: its named design's intent, else its `intent` field (the
    offline planner's reading when the backend asks no model), else nothing."""
    from keymps.planning.named_design import to_intent

    design = getattr(answer, "design", None)
    if design is not None:
        read, _ = to_intent(design)
        if read is None:
            return ()
        return (replace(intent_of_design(read, source="design"), object_id=design.object),)
    stated = getattr(answer, "intent", None)
    if stated is None:
        return ()
    source: IntentSource = "answer" if asks_model else "offline"
    claims = []
    for each in stated if isinstance(stated, list) else [stated]:
        claim, _ = intent_of_answer(each, family, source)
        if claim is not None:
            claims.append(claim)
    return tuple(claims)
