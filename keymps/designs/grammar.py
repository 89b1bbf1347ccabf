"""The offline planner's instruction grammar: a sentence to a design intent, deterministically.

It reads counts (digits or words), lengths (mm, cm, m, inches), directions (vertically,
horizontally, lengthwise, crosswise), and the kitchen phrases of the KeyMPs paper's cases ("N
people", "each day of this week", "both tips", "around", "layers", "spiral", "N-pointed star",
"27th birthday", "each of the N slices" ...). A sentence it cannot read raises
UnreadableInstruction, which says what it did understand.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Literal

from keymps.designs.words import (
    ICING_WORDS,
    LENGTH,
    NUMBER,
    PEOPLE,
    PIECES,
    UNIT_RE,
    UNITS,
    normalise,
)
from keymps.errors import KeympsError

Family = Literal["cut", "icing"]
Design = Literal[
    "equal",  # N equal parts: wedges on round objects, a grid on square ones, slices on long ones
    "parallel",  # N equal parts by parallel cuts in the given direction
    "width",  # slices of a given width (a given count, or as many as fit)
    "middle",  # one cut through the middle
    "tips",  # cut off both tips
    "dots_ring",  # dots around the object
    "rings",  # concentric icing lines
    "dots_spiral",  # a ring of dots and a spiral inside
    "spiral",
    "star",
    "digits",
    "dot_per_slice",
    "free",  # the user leaves the design to the planner
]
Orientation = Literal["vertical", "horizontal", "lengthwise", "crosswise"]


class UnreadableInstruction(KeympsError):
    """The offline planner cannot turn the sentence into a design."""


@dataclass(frozen=True)
class Intent:
    family: Family
    design: Design
    count: int | None = None
    """Parts, slices, dots, layers or star points, depending on the design."""
    slice_width_mm: float | None = None
    object_length_mm: float | None = None
    """A length the user states for the object (scales slice widths to the picture)."""
    orientation: Orientation | None = None
    text: str | None = None
    """Characters for the seven-segment design."""
    understood: tuple[str, ...] = field(default_factory=tuple)

    def describe(self) -> str:
        parts = [f"{self.family}: {self.design.replace('_', ' ')}"]
        if self.count is not None:
            parts.append(f"count {self.count}")
        if self.slice_width_mm is not None:
            parts.append(f"slices {self.slice_width_mm / 10:g} cm wide")
        if self.object_length_mm is not None:
            parts.append(f"object {self.object_length_mm / 10:g} cm long")
        if self.orientation:
            parts.append(self.orientation)
        if self.text:
            parts.append(f"text {self.text!r}")
        return ", ".join(parts)


@dataclass
class _Reader:
    text: str
    understood: list[str] = field(default_factory=list)

    def find(self, pattern: str) -> re.Match[str] | None:
        match = re.search(pattern, self.text)
        if match:
            self.understood.append(match.group(0).strip())
        return match

    def has(self, pattern: str) -> bool:
        return re.search(pattern, self.text) is not None


def _mm(value: str, unit: str) -> float:
    return float(value) * UNITS[unit]


def _object_length(reader: _Reader) -> float | None:
    patterns = [
        rf"\b(?:is|it's|about|approximately|roughly)\s+{LENGTH}\s+long\b",
        rf"\blength\s+(?:of\s+|is\s+)?{LENGTH}",
        rf"\b{LENGTH}\s+long\b",
        rf"\b(?:this|the|a|an|my)\s+{LENGTH}\s+(?!{PIECES}|thick|wide|apart)[a-z]+",
    ]
    for pattern in patterns:
        match = reader.find(pattern)
        if match:
            return _mm(match.group(1), match.group(2))
    return None


def _slice_width(reader: _Reader) -> float | None:
    patterns = [
        rf"{LENGTH}\s+(?:thick\s+|wide\s+)?{PIECES}",
        rf"{PIECES}\s+(?:of\s+|about\s+|each\s+)*{LENGTH}",
        rf"{LENGTH}\s+(?:thick|wide|apart|intervals?|each)\b",
        rf"\bevery\s+{LENGTH}",
    ]
    for pattern in patterns:
        match = reader.find(pattern)
        if match:
            return _mm(match.group(1), match.group(2))
    return None


def _orientation(reader: _Reader) -> Orientation | None:
    if reader.find(r"\bvertical(?:ly)?\b|\bup and down\b|\btop to bottom\b"):
        return "vertical"
    if reader.find(r"\bhorizontal(?:ly)?\b|\bleft to right\b|\bside to side\b"):
        return "horizontal"
    if reader.find(r"\blength-?wise\b|\balong (?:its|the) length\b"):
        return "lengthwise"
    if reader.find(r"\bcross-?wise\b|\bacross\b"):
        return "crosswise"
    return None


def _part_count(reader: _Reader) -> int | None:
    """How many parts, slices or portions the sentence asks for (None if it does not say)."""
    if reader.find(
        r"\b(?:each|every|1 \w+ (?:for|per) each)\s+day\s+(?:of\s+)?(?:this|the|a)\s+week\b"
    ):
        return 7
    if reader.find(r"\bfor (?:a|the|this) week\b|\b7 days\b"):
        return 7
    match = reader.find(rf"\b(\d+)\s+(?:hungry\s+|other\s+)?{PEOPLE}")
    if match:
        return int(match.group(1))
    match = reader.find(
        rf"\b(\d+)\s+(?:{NUMBER}\s*{UNIT_RE}\s+)?(?:equal\s+|even\s+|thin\s+|thick\s+|"
        rf"same[- ]sized?\s+|similar\s+)*{PIECES}"
    )
    followed = reader.text[match.end() :] if match else ""
    if match and not re.match(r"\s*(?:for|per)\s+(?:each|every)", followed):
        return int(match.group(1))
    match = reader.find(rf"\b(?:into|in)\s+(\d+)\b(?!\s*(?:\.\d)?\s*{UNIT_RE}\b)")
    if match:
        return int(match.group(1))
    if reader.find(r"\bin half\b|\bhalve\b|\bin 2\b|\bhalves\b"):
        return 2
    if reader.find(r"\bin thirds\b|\binto thirds\b"):
        return 3
    if reader.find(r"\bquarters?\b|\bquarter it\b"):
        return 4
    return None


def _icing_intent(reader: _Reader) -> Intent | None:
    understood = reader.understood
    match = reader.find(
        rf"\b(?:1|a|an) (?:\w+ )?(?:dot|drop|rosette|blob)s?\b.*\beach of (?:the )?(\d+) {PIECES}"
    ) or reader.find(
        rf"\b(?:dot|rosette)s? (?:on|in) (?:the middle of )?each of (?:the )?(\d+) {PIECES}"
    )
    if match:
        return Intent(
            "icing", "dot_per_slice", count=int(match.group(1)), understood=tuple(understood)
        )
    match = reader.find(r"\b(\d+)(?:st|nd|rd|th) birthday\b") or reader.find(
        r"\b(?:digits?|numbers?|number|write|seven[- ]segment\w*)\s+(?:of\s+|the\s+)?(\d+)\b"
    )
    if match and (reader.has(r"digit|seven[- ]segment|number|write|birthday")):
        return Intent("icing", "digits", text=match.group(1), understood=tuple(understood))
    if reader.has(r"\bstar\b"):
        match = reader.find(r"\b(\d+)[- ]?(?:pointed|point|pointy)\s+star\b") or reader.find(
            r"\bstar\s+with\s+(\d+)\s+(?:points|tips|arms)\b"
        )
        count = int(match.group(1)) if match else 5
        if not match:
            reader.find(r"\bstar\b")
        return Intent("icing", "star", count=count, understood=tuple(understood))
    dots_around = reader.has(r"\b(?:dots?|icings|rosettes?|drops?|blobs?)\b") and reader.has(
        r"\baround\b|\bborder\b|\bedge\b|\brim\b|\bcircle\b"
    )
    if reader.has(r"\bspiral|\bswirl"):
        reader.find(r"\bspiral\w*|\bswirl\w*")
        if dots_around:
            reader.find(r"\bdots? around\b|\baround\b")
            return Intent(
                "icing", "dots_spiral", count=_dot_count(reader), understood=tuple(understood)
            )
        return Intent("icing", "spiral", understood=tuple(understood))
    match = reader.find(r"\b(\d+) (?:layers?|rings?|circles?|lines)\b")
    if match and reader.has(r"\baround\b|\blayers?\b|\brings?\b|\bcircles?\b"):
        return Intent("icing", "rings", count=int(match.group(1)), understood=tuple(understood))
    if reader.has(r"\blayers?\b|\brings? of icing\b|\bicing (?:line|ring) around\b"):
        reader.find(r"\blayers?\b|\brings?\b|\bline\b")
        return Intent("icing", "rings", count=1, understood=tuple(understood))
    if dots_around or reader.has(r"\b\d+ icings\b|\b\d+ (?:icing )?dots\b"):
        reader.find(r"\baround\b|\bborder\b|\bedge\b")
        return Intent("icing", "dots_ring", count=_dot_count(reader), understood=tuple(understood))
    if reader.find(
        r"\b(?:simple|interesting|any|nice|pretty|beautiful|creative|random|your own)\b.*\bdesign\b"
        r"|\bsurprise me\b|\bdecorate (?:it|the cake)\b"
    ):
        return Intent("icing", "free", understood=tuple(understood))
    return None


def _dot_count(reader: _Reader) -> int | None:
    match = reader.find(r"\b(\d+)\s+(?:icing\s+)?(?:dots?|icings?|rosettes?|drops?|blobs?)\b")
    return int(match.group(1)) if match else None


def _cut_intent(reader: _Reader) -> Intent | None:
    understood = reader.understood
    if reader.find(r"\b(?:both|2|the 2)\s+(?:tips|ends)\b|\b(?:tips|ends) off\b|\btop and tail\b"):
        return Intent("cut", "tips", understood=tuple(understood))
    object_length = _object_length(reader)
    width = _slice_width(reader)
    orientation = _orientation(reader)
    count = _part_count(reader)
    if width is not None:
        counted = re.search(
            rf"\b(\d+)\s+(?:{NUMBER}\s*-?\s*{UNIT_RE}\s+)?(?:thin\s+|thick\s+|wide\s+)?{PIECES}",
            reader.text,
        )
        slice_count = int(counted.group(1)) if counted else None
        if slice_count is None and re.search(
            rf"\b(?:a|an)\s+{LENGTH}\s+(?:thick\s+|wide\s+)?(?:slice|piece|strip)\b", reader.text
        ):
            slice_count = 1
        return Intent(
            "cut",
            "width",
            count=slice_count,
            slice_width_mm=width,
            object_length_mm=object_length,
            orientation=orientation,
            understood=tuple(understood),
        )
    middle = reader.has(r"\b(?:middle|centre|center|half)\b")
    if middle and (count in (None, 1) or reader.has(r"\b1 (?:\w+ )?(?:slice|cut)\b")):
        reader.find(r"\bmiddle\b|\bcent(?:re|er)\b|\bhalf\b")
        return Intent(
            "cut", "middle", count=1, orientation=orientation, understood=tuple(understood)
        )
    if count is not None and count >= 2:
        design: Design = "parallel" if orientation else "equal"
        return Intent(
            "cut", design, count=count, orientation=orientation, understood=tuple(understood)
        )
    return None


def read_instruction(sentence: str) -> Intent:
    """The design the sentence asks for, or UnreadableInstruction saying what was understood."""
    text = normalise(sentence)
    reader = _Reader(text)
    vague = re.search(
        rf"\b(?:a few|several|some|many|a lot of|lots of)\s+(?:\w+\s+)?{PIECES}", text
    )
    if vague:
        raise UnreadableInstruction(
            unreadable_message(sentence, [f"{vague.group(0)!r} does not say how many"])
        )
    icing_words = reader.has(ICING_WORDS)
    intent = _icing_intent(reader) if icing_words else None
    if intent is None:
        intent = _cut_intent(_Reader(text))
    if intent is None:
        raise UnreadableInstruction(unreadable_message(sentence, reader.understood))
    _check_numbers(intent)
    return intent


MAX_COUNT = 1000
"""The largest count the offline planner lays out (planner.max_pairs limits the plan anyway)."""


def _check_numbers(intent: Intent) -> None:
    if intent.count is not None and not 1 <= intent.count <= MAX_COUNT:
        raise KeympsError(
            f"the offline planner read a count of {intent.count} ({intent.describe()}); "
            f"it lays out 1 to {MAX_COUNT}"
        )
    for what, value in (
        ("slice width", intent.slice_width_mm),
        ("length", intent.object_length_mm),
    ):
        if value is not None and not 0.5 <= value <= 10_000:
            raise KeympsError(
                f"the offline planner read a {what} of {value:g} mm; it must be 0.5 mm to 10 m"
            )
    if intent.design == "star" and intent.count is not None and intent.count < 3:
        raise KeympsError(f"a star needs at least 3 points, not {intent.count}")


def unreadable_message(sentence: str, understood: list[str]) -> str:
    seen = (
        f"understood only: {', '.join(repr(u) for u in understood)}"
        if understood
        else ("understood nothing it can build")
    )
    return (
        f"the offline planner cannot turn {sentence.strip()!r} into a design ({seen}). It reads "
        "counts of slices/parts/people ('into 8 equal slices', 'for 10 people', 'each day of this "
        "week'), slice widths ('5 cm slices'), 'vertically'/'horizontally', 'both tips', 'a slice "
        "in the middle', and icing designs (N dots around, N layers, spiral, N-pointed star, "
        "digits, a dot on each of N slices). Rephrase, or plan with a VLM: --model "
        "openai/gpt-4o (or any litellm model; see docs/vlm.md)"
    )
