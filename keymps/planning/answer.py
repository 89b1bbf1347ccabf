"""The planner's answer: its JSON schema, a tolerant parser, and the validation rules.

Answer shape (other tools and prompts rely on it), points in pixels of the crop that was sent:
    {"keyword": "sawing", "pairs": [[[x0, y0], [x1, y1]], ...], "rationale": "..."}
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from keymps.config.limits import max_answer_chars
from keymps.types import Step

Coordinate = Annotated[float, Field(strict=True)]
"""A JSON number: true, "12" or null are wrong types, sent back for repair, never coerced."""
Point = tuple[Coordinate, Coordinate]
Pair = tuple[Point, Point]


class PlanAnswer(BaseModel):
    """A combined answer: which primitive, and K keypoint pairs in crop pixels."""

    model_config = ConfigDict(extra="ignore")
    keyword: str
    pairs: list[Pair]
    rationale: str = ""


class KeywordAnswer(BaseModel):
    model_config = ConfigDict(extra="ignore")
    keyword: str
    rationale: str = ""


class PairsAnswer(BaseModel):
    model_config = ConfigDict(extra="ignore")
    pairs: list[Pair]
    rationale: str = ""


ANSWER_MODELS: dict[str, type[BaseModel]] = {
    "combined": PlanAnswer,
    "keyword": KeywordAnswer,
    "pairs": PairsAnswer,
}


def answer_schema(step: Step, keywords: Sequence[str], max_pairs: int) -> dict[str, Any]:
    """The JSON schema sent for structured output (OpenAI strict-mode compatible)."""
    point = {
        "type": "array",
        "description": "[x, y] in pixels of the image sent; origin top-left, x right, y down",
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
    if step in ("combined", "pairs"):
        properties["pairs"] = {
            "type": "array",
            "description": f"1 to {max_pairs} keypoint pairs",
            "items": pair,
        }
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


_FENCE = re.compile(r"```(?:json|JSON)?\s*(.*?)```", re.DOTALL)


def extract_json(text: str) -> Any:
    """The JSON object in a model's text: plain, in a code fence, or surrounded by prose."""
    candidates = [text.strip()]
    candidates += [m.group(1).strip() for m in _FENCE.finditer(text)]
    try:
        for candidate in candidates:
            try:
                return json.loads(candidate)
            except json.JSONDecodeError:
                pass
        # the first "{" that starts a complete JSON value; raw_decode keeps this linear-ish
        # (a scan per "{" in Python was quadratic: 100 KB of braces took minutes)
        decoder = json.JSONDecoder()
        start = text.find("{")
        while start != -1:
            try:
                return decoder.raw_decode(text, start)[0]
            except json.JSONDecodeError:
                start = text.find("{", start + 1)
    except RecursionError:
        raise ValueError("the JSON is nested too deeply") from None
    raise ValueError("no JSON object found in the answer")


def parse_and_validate(
    text: str,
    step: Step,
    keywords: Sequence[str],
    crop_size_px: tuple[int, int],
    max_pairs: int,
) -> tuple[BaseModel | None, list[str]]:
    """(answer, []) when valid, else (None, the problems in words a model can act on)."""
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
    pairs = getattr(answer, "pairs", None)
    if pairs is not None:
        problems += _pair_problems(pairs, crop_size_px, max_pairs)
    return (None, problems) if problems else (answer, [])


def normalise_keyword(keyword: str, keywords: Sequence[str]) -> str:
    """The listed name a keyword means despite case, spaces, quotes or brackets ("[Sawing]")."""
    bare = keyword.strip().strip("[]()'\"`* ").strip().lower()
    matches = [k for k in keywords if k.lower() == bare]
    return matches[0] if len(matches) == 1 else keyword


def _pair_problems(pairs: list[Pair], crop_size_px: tuple[int, int], max_pairs: int) -> list[str]:
    width, height = crop_size_px
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
