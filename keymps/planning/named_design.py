"""Named designs as answers: `{"design": {"name": "dots_ring", "count": 9}}` instead of pairs.

A backend that understands "six equal parts" but cannot draw them precisely may name the design
from the offline planner's catalogue (the Intent designs of keymps.designs.grammar) with its
parameters; keymps then lays it out exactly on the measured object (keymps.designs.place).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from keymps.designs.grammar import CUT_DESIGNS, Intent

ORIENTATIONS = ("vertical", "horizontal", "lengthwise", "crosswise")


@dataclass(frozen=True)
class CatalogueEntry:
    """A named design the offline catalogue offers to a VLM, with its parameters."""

    name: str
    family: str
    """cutting or icing (the primitive family it needs)."""
    meaning: str
    required: tuple[str, ...] = ()
    optional: tuple[str, ...] = ()


CATALOGUE: tuple[CatalogueEntry, ...] = (
    CatalogueEntry("equal", "cutting", "N equal parts: wedges through the centre of a round "
                   "object, an equal grid on a square one, parallel slices on a long one",
                   ("count",)),
    CatalogueEntry("parallel", "cutting", "N equal parts by N - 1 parallel cuts in a direction",
                   ("count", "orientation")),
    CatalogueEntry("width", "cutting", "slices of a given width from one end (count of them, "
                   "or as many as fit with an end piece of at least half a slice)",
                   ("slice_width_cm",), ("count", "orientation", "object_length_cm")),
    CatalogueEntry("middle", "cutting", "one cut through the middle", (), ("orientation",)),
    CatalogueEntry("tips", "cutting", "cut off both tips (10 % of the length in from each end)"),
    CatalogueEntry("dot", "icing", "one dot in the middle"),
    CatalogueEntry("dots_ring", "icing", "dots evenly spaced around the object, away from the "
                   "edge; `layers` concentric rings of dots", (), ("count", "layers")),
    CatalogueEntry("rings", "icing", "N concentric icing lines around the object", ("count",)),
    CatalogueEntry("dots_spiral", "icing", "a ring of dots and a spiral inside", (), ("count",)),
    CatalogueEntry("spiral", "icing", "a spiral from the centre"),
    CatalogueEntry("star", "icing", "an N-pointed star in the middle", (), ("count",)),
    CatalogueEntry("digits", "icing", "digits in seven-segment strokes, centred", ("text",)),
    CatalogueEntry("dot_per_slice", "icing", "one dot at the middle of each of N equal pieces",
                   ("count",)),
    CatalogueEntry("free", "icing", "a fixed free design: a ring of dots and a star"),
)  # fmt: skip
BY_NAME = {entry.name: entry for entry in CATALOGUE}
PARAMETERS = {
    "count": "integer: parts, slices, dots (per ring), rings or star points",
    "layers": "integer: rings of dots (dots_ring)",
    "slice_width_cm": "number: slice width in centimetres (width)",
    "object_length_cm": "number: the object's length the user states, centimetres (width)",
    "orientation": "one of vertical, horizontal, lengthwise, crosswise",
    "text": "string of digits (digits)",
}


class DesignAnswer(BaseModel):
    """The `design` field of an answer; absent parameters are null."""

    model_config = ConfigDict(extra="forbid")
    name: str
    count: int | None = Field(default=None, strict=True)
    layers: int | None = Field(default=None, strict=True)
    slice_width_cm: float | None = None
    object_length_cm: float | None = None
    orientation: str | None = None
    text: str | None = None
    object: int | None = Field(default=None, strict=True)
    """With several objects: the id (as numbered on the image) of the object it is for."""


def design_schema(family: str | None) -> dict[str, Any]:
    """The JSON schema of the `design` field (OpenAI strict: every field present, maybe null)."""
    names = [e.name for e in CATALOGUE if family is None or e.family == family]

    def nullable(kind: str, description: str, **extra: Any) -> dict[str, Any]:
        return {"type": [kind, "null"], "description": description, **extra}

    return {
        "type": "object",
        "description": "a named design keymps lays out exactly on the object",
        "properties": {
            "name": {"type": "string", "enum": names},
            "count": nullable("integer", PARAMETERS["count"]),
            "layers": nullable("integer", PARAMETERS["layers"]),
            "slice_width_cm": nullable("number", PARAMETERS["slice_width_cm"]),
            "object_length_cm": nullable("number", PARAMETERS["object_length_cm"]),
            "orientation": nullable(
                "string", PARAMETERS["orientation"], enum=[*ORIENTATIONS, None]
            ),
            "text": nullable("string", PARAMETERS["text"]),
            "object": nullable(
                "integer", "with several objects: the id of the object it is for; else null"
            ),
        },
        "required": ["name", *PARAMETERS, "object"],
        "additionalProperties": False,
    }


def catalogue_text(family: str | None) -> str:
    """The designs of a family as prompt lines: '- name (parameters): meaning'."""
    lines = []
    for entry in CATALOGUE:
        if family is not None and entry.family != family:
            continue
        params = [*entry.required, *(f"{p}?" for p in entry.optional)]
        shown = f" ({', '.join(params)})" if params else ""
        lines.append(f"- {entry.name}{shown}: {entry.meaning}")
    return "\n".join(lines)


def design_answer(intent: Intent) -> dict[str, Any]:
    """The `design` answer that names `intent` (the inverse of to_intent)."""
    return {
        "name": intent.design,
        "count": intent.count if intent.design != "middle" else None,
        "layers": intent.layers,
        "slice_width_cm": intent.slice_width_mm / 10 if intent.slice_width_mm else None,
        "object_length_cm": intent.object_length_mm / 10 if intent.object_length_mm else None,
        "orientation": intent.orientation,
        "text": intent.text,
    }


def to_intent(answer: DesignAnswer) -> tuple[Intent | None, list[str]]:
    """(the Intent, []) or (None, the problems, in words a model can act on)."""
    entry = BY_NAME.get(answer.name)
    if entry is None:
        return None, [f"design.name {answer.name!r} is not one of: {', '.join(BY_NAME)}"]
    problems = []
    given = {k for k in PARAMETERS if getattr(answer, k) is not None}
    for name in entry.required:
        if name not in given:
            problems.append(f"design {entry.name} needs {name} ({PARAMETERS[name]})")
    for name in sorted(given - set(entry.required) - set(entry.optional)):
        problems.append(f"design {entry.name} takes no {name}; set it to null")
    for name in ("count", "layers"):
        value = getattr(answer, name)
        if value is not None and not 1 <= value <= 1000:
            problems.append(f"design.{name} {value} must be 1 to 1000")
    for name in ("slice_width_cm", "object_length_cm"):
        value = getattr(answer, name)
        if value is not None and not (math.isfinite(value) and 0.05 <= value <= 1000):
            problems.append(f"design.{name} {value} must be 0.05 to 1000 cm")
    if answer.orientation is not None and answer.orientation not in ORIENTATIONS:
        problems.append(f"design.orientation must be one of {', '.join(ORIENTATIONS)}")
    if answer.text is not None and not (answer.text.isdigit() and len(answer.text) <= 12):
        problems.append("design.text must be 1 to 12 digits (seven-segment digits only)")
    if entry.name == "equal" and answer.count == 1:
        problems.append("design equal needs count >= 2 (one cut through the middle is 'middle')")
    if entry.name == "star" and answer.count is not None and answer.count < 3:
        problems.append("design star needs count >= 3")
    if problems:
        return None, problems
    family = "cut" if entry.name in CUT_DESIGNS else "icing"
    intent = Intent(
        family,  # type: ignore[arg-type]
        entry.name,  # type: ignore[arg-type]
        count=answer.count if entry.name != "middle" else 1,
        slice_width_mm=answer.slice_width_cm * 10 if answer.slice_width_cm else None,
        object_length_mm=answer.object_length_cm * 10 if answer.object_length_cm else None,
        orientation=answer.orientation,  # type: ignore[arg-type]
        text=answer.text,
        layers=answer.layers if (answer.layers or 1) > 1 else None,
    )
    return intent, []
