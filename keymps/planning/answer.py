"""The planner's answer: its JSON schema, a tolerant parser, and the validation rules.

Answer shape (other tools and prompts rely on it), points in the coordinate convention of the
image that was sent (keymps.planning.coordinates; pixels by default):
    {"keyword": "sawing", "pairs": [[[x0, y0], [x1, y1]], ...], "rationale": "..."}
or, with `planner.answer: design | either`, a named design (keymps.planning.named_design):
    {"keyword": "line", "design": {"name": "dots_ring", "count": 9, ...}, "rationale": "..."}
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Sequence
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from keymps.config.limits import max_answer_chars
from keymps.planning.intent import IntentAnswer, intent_of_answer, intent_schema
from keymps.planning.named_design import DesignAnswer, design_schema
from keymps.types import AnswerMode, Step

ANSWER_MODES: tuple[str, ...] = ("pairs", "design", "either")

Coordinate = Annotated[float, Field(strict=True)]
"""A JSON number: true, "12" or null are wrong types, sent back for repair, never coerced."""
Point = tuple[Coordinate, Coordinate]
Pair = tuple[Point, Point]


class PlanAnswer(BaseModel):
    """A combined answer: which primitive, and K keypoint pairs in crop pixels."""

    model_config = ConfigDict(extra="ignore")
    keyword: str
    pairs: list[Pair] | None = None
    design: DesignAnswer | None = None
    intent: IntentAnswer | list[IntentAnswer] | None = None
    """What the pairs achieve (one per object with several), checked before anything moves."""
    rationale: str = ""


class KeywordAnswer(BaseModel):
    model_config = ConfigDict(extra="ignore")
    keyword: str
    rationale: str = ""


class PairsAnswer(BaseModel):
    model_config = ConfigDict(extra="ignore")
    pairs: list[Pair] | None = None
    design: DesignAnswer | None = None
    intent: IntentAnswer | list[IntentAnswer] | None = None
    rationale: str = ""


ANSWER_MODELS: dict[str, type[BaseModel]] = {
    "combined": PlanAnswer,
    "keyword": KeywordAnswer,
    "pairs": PairsAnswer,
}


POINT_DESCRIPTIONS = {
    "pixels": "[x, y] in pixels of the image sent; origin top-left, x right, y down",
    "xy_1000": "[x, y] normalized to 0-1000; origin top-left, x right, y down",
    "yx_1000": "[y, x] normalized to 0-1000; origin top-left, y down, x right",
}


def answer_schema(
    step: Step,
    keywords: Sequence[str],
    max_pairs: int,
    answer: AnswerMode = "pairs",
    convention: str = "pixels",
    family: str | None = None,
) -> dict[str, Any]:
    """The JSON schema sent for structured output (OpenAI strict-mode compatible).

    `answer` either: `pairs` and `design` are both present and one of them is null (a union
    that strict mode accepts); `family` limits the design names to the task's family.
    """
    point = {
        "type": "array",
        "description": POINT_DESCRIPTIONS[convention],
        "items": {"type": "number"},
    }
    pair = {"type": "array", "description": "[start, end]; start = end makes a dot", "items": point}
    properties: dict[str, Any] = {}
    if step in ("combined", "keyword"):
        properties["keyword"] = {
            "type": "string",
            "enum": list(keywords),
            "description": "the primitive to use, one of the listed names",
        }
    if step in ("combined", "pairs") and answer in ("pairs", "either"):
        properties["pairs"] = {
            "type": ["array", "null"] if answer == "either" else "array",
            "description": f"1 to {max_pairs} keypoint pairs"
            + ("; null when a design is named" if answer == "either" else ""),
            "items": pair,
        }
    if step in ("combined", "pairs") and answer in ("design", "either"):
        design = design_schema(family)
        if answer == "either":
            design = {"anyOf": [design, {"type": "null"}]}
        properties["design"] = design
    if step in ("combined", "pairs") and answer in ("pairs", "either"):
        properties["intent"] = intent_schema()
    properties["rationale"] = {"type": "string", "description": "one or two sentences"}
    return strict_object_schema(f"keymps_{step}_answer", properties)


def strict_object_schema(name: str, properties: dict[str, Any]) -> dict[str, Any]:
    """A named JSON schema for an object with exactly these properties, all required (the form
    OpenAI's strict structured output accepts)."""
    return {
        "name": name,
        "strict": True,
        "schema": {
            "type": "object",
            "properties": properties,
            "required": list(properties),
            "additionalProperties": False,
        },
    }


def extract_json(text: str) -> Any:
    """The one JSON object in a model's text: plain, in a code fence, or surrounded by prose.

    An answer holding two different objects is refused, not read by its first: which of them
    the model meant is a guess (a repeat of the same object is one answer).
    """
    try:
        try:
            return json.loads(text)
        except json.JSONDecodeError:
            pass
        objects = _top_level_objects(text)
        first = next(objects, _NONE)
        # the first that differs settles it: counting every distinct one compared them pairwise
        differs = any(value != first for value in objects)
    except RecursionError:
        raise ValueError("the JSON is nested too deeply") from None
    if first is _NONE:
        raise ValueError("no JSON object found in the answer")
    if differs:
        raise ValueError("it holds at least 2 different JSON objects, and only one is read")
    return first


_NONE = object()
"""No JSON value in the text (null is a value)."""


def _top_level_objects(text: str) -> Iterator[Any]:
    """Every complete JSON value that starts at a "{" outside the values found before it.

    raw_decode from each "{" keeps this linear-ish (a scan per "{" in Python was quadratic:
    100 KB of braces took minutes); code fences are prose around the object like any other.
    """
    decoder = json.JSONDecoder()
    start = text.find("{")
    while start != -1:
        try:
            value, end = decoder.raw_decode(text, start)
        except json.JSONDecodeError:
            start = text.find("{", start + 1)
            continue
        yield value
        start = text.find("{", end)


def parse_and_validate(
    text: str,
    step: Step,
    keywords: Sequence[str],
    crop_size_px: tuple[int, int],
    max_pairs: int,
    answer_mode: AnswerMode = "pairs",
    convention: str = "pixels",
    family: str = "cutting",
) -> tuple[BaseModel | None, list[str]]:
    """(answer, []) when valid, else (None, the problems in words a model can act on).

    `crop_size_px` is the size of the image sent; points are checked in `convention`.
    `family` (cutting, icing): a cut needs its two points apart; no family repeats a pair.
    """
    longest = max_answer_chars(max_pairs)
    if len(text) > longest:
        return None, [
            f"the answer is {len(text)} characters long; at most {longest} are read for up to "
            f"{max_pairs} pairs: answer with the JSON only"
        ]
    try:
        data = extract_json(text)
    except ValueError as error:
        return None, [f"the answer is not a JSON object ({error}); answer with the JSON only"]
    if not isinstance(data, dict):
        return None, ["the answer must be a JSON object with the fields of the schema"]
    try:
        answer = ANSWER_MODELS[step].model_validate(data)
    except ValidationError as error:
        problems = []
        for item in error.errors(include_url=False)[:12]:
            where = ".".join(str(p) for p in item["loc"]) or "(answer)"
            problems.append(f"{where}: {item['msg']}")
        if error.error_count() > 12:
            problems.append(f"... ({error.error_count() - 12} more problems not listed)")
        return None, problems
    problems = []
    keyword = getattr(answer, "keyword", None)
    if keyword is not None and keyword not in keywords:
        keyword = normalise_keyword(keyword, keywords)
        answer = answer.model_copy(update={"keyword": keyword})
    if keyword is not None and keyword not in keywords:
        problems.append(f"keyword {keyword!r} is not one of: {', '.join(keywords)}")
    if step != "keyword":
        problems += _form_problems(answer, answer_mode)
    pairs = getattr(answer, "pairs", None)
    if pairs is not None:
        problems += _pair_problems(pairs, crop_size_px, max_pairs, convention)
        if not problems:
            problems += _geometry_problems(pairs, crop_size_px, convention, family)
    design = getattr(answer, "design", None)
    if design is not None:
        from keymps.planning.named_design import to_intent

        problems += to_intent(design)[1]
    for stated in stated_intents(answer):
        problems += intent_of_answer(stated, family)[1]
    return (None, problems) if problems else (answer, [])


def stated_intents(answer: BaseModel) -> list[IntentAnswer]:
    """The answer's `intent` field as a list (empty when absent)."""
    stated = getattr(answer, "intent", None)
    if stated is None:
        return []
    return stated if isinstance(stated, list) else [stated]


def _form_problems(answer: BaseModel, mode: AnswerMode) -> list[str]:
    """Pairs or a design, as `planner.answer` allows: exactly one of them."""
    pairs, design = getattr(answer, "pairs", None), getattr(answer, "design", None)
    if mode == "pairs" and pairs is None:
        return ["pairs: give the keypoint pairs"]
    if mode == "pairs" and design is not None:
        return ["design: this task takes keypoint pairs only; drop the design"]
    if mode == "design" and design is None:
        return ["design: name a design from the list (this task takes no raw pairs)"]
    if mode == "design" and pairs is not None:
        return ["pairs: this task takes a named design only; set pairs to null"]
    if mode == "either" and (pairs is None) == (design is None):
        return ["give either pairs or a design (the other null), not both and not neither"]
    return []


def normalise_keyword(keyword: str, keywords: Sequence[str]) -> str:
    """The listed name a keyword means despite case, spaces, quotes or brackets ("[Sawing]")."""
    bare = keyword.strip().strip("[]()'\"`* ").strip().lower()
    matches = [k for k in keywords if k.lower() == bare]
    return matches[0] if len(matches) == 1 else keyword


def _pair_problems(
    pairs: list[Pair], crop_size_px: tuple[int, int], max_pairs: int, convention: str = "pixels"
) -> list[str]:
    width, height = crop_size_px
    if convention != "pixels":
        return _normalized_problems(pairs, max_pairs, convention)
    problems = []
    if not 1 <= len(pairs) <= max_pairs:
        problems.append(f"pairs: {len(pairs)} pairs given; give between 1 and {max_pairs}")
    for index, pair in enumerate(pairs):
        for which, (x, y) in zip(("start", "end"), pair, strict=True):
            if not (math.isfinite(x) and math.isfinite(y)):
                problems.append(f"pair {index + 1} {which} ({x}, {y}) is not a finite number")
            elif not (0 <= x <= width and 0 <= y <= height):
                problems.append(
                    f"pair {index + 1} {which} ({x:g}, {y:g}) is outside the image: "
                    f"x must be in 0..{width}, y in 0..{height}"
                )
        if len(problems) > 12:
            problems.append("... (more problems not listed)")
            break
    return problems


MIN_CUT_SHARE = 0.02
"""A cut shorter than this share of the image's shorter side has no direction to cut along."""


def _geometry_problems(
    pairs: list[Pair], crop_size_px: tuple[int, int], convention: str, family: str
) -> list[str]:
    """Pairs no motion can follow: a cut whose start and end (nearly) coincide, and a pair
    given twice (the same cut, either way round, or the same dot: icing piled on icing)."""
    scale = 1000.0 if convention != "pixels" else float(min(crop_size_px))
    shortest = MIN_CUT_SHARE * scale
    first_of: dict[tuple[float, ...], int] = {}
    problems = []
    for index, (start, end) in enumerate(pairs):
        length = math.dist(start, end)
        if family == "cutting" and length < shortest:
            problems.append(
                f"pair {index + 1} is a cut {length:g} long from {list(start)} to {list(end)}: "
                f"a cut needs its start and end apart (at least {shortest:g})"
            )
        key = tuple(round(v) for v in (*start, *end))  # the same to a pixel (or 1/1000)
        turned = tuple(round(v) for v in (*end, *start))
        earlier = first_of.get(key, first_of.get(turned) if family == "cutting" else None)
        if earlier is not None:
            problems.append(f"pair {index + 1} repeats pair {earlier + 1}: give each once")
        first_of.setdefault(key, index)
        if len(problems) > 12:
            problems.append("... (more problems not listed)")
            break
    return problems


def _normalized_problems(pairs: list[Pair], max_pairs: int, convention: str) -> list[str]:
    order = "[y, x]" if convention == "yx_1000" else "[x, y]"
    problems = []
    if not 1 <= len(pairs) <= max_pairs:
        problems.append(f"pairs: {len(pairs)} pairs given; give between 1 and {max_pairs}")
    for index, pair in enumerate(pairs):
        for which, (a, b) in zip(("start", "end"), pair, strict=True):
            if not (math.isfinite(a) and math.isfinite(b)):
                problems.append(f"pair {index + 1} {which} ({a}, {b}) is not a finite number")
            elif not (0 <= a <= 1000 and 0 <= b <= 1000):
                problems.append(
                    f"pair {index + 1} {which} [{a:g}, {b:g}] is outside the image: points are "
                    f"{order} normalized to 0..1000"
                )
        if len(problems) > 12:
            problems.append("... (more problems not listed)")
            break
    return problems
