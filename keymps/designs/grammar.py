"""The offline planner's instruction grammar: a sentence to a design intent, deterministically.

It reads counts (digits or words, wherever they stand: "eighteen little dots"), lengths in
every written form (mm, cm, m, inches, '"'; "half an inch", "1/2", "one and a half": see
keymps.designs.quantities), directions (vertically, horizontally, lengthwise, crosswise: the
object's own axes), distances from the edge for rings, and the kitchen phrases of the KeyMPs
paper's cases ("N people", "each day of this week", "both tips", "around", "layers", "spiral",
"N-pointed star", "27th birthday", "each of the N slices" ...).

It never guesses: every number and unit of the sentence belongs to a phrase it read, or the
sentence is refused naming the words left over (keymps.designs.refusals).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import Literal

from keymps.designs.quantities import LENGTH_UNITS
from keymps.designs.refusals import (
    CAPABILITIES,
    VLM_HINT,
    UnreadableInstruction,
    as_written,
    refuse_ambiguous_fractions,
    refuse_fractional_counts,
    refuse_misspelled_counts,
    refuse_second_design,
    refuse_unknown_design,
    refuse_unmodelled,
    unreadable_message,
)
from keymps.designs.words import (
    COUNT,
    DOTS,
    FILLER,
    ICING_WORDS,
    LENGTH,
    NUMBER,
    PEOPLE,
    PIECES,
    UNIT_RE,
    UNITS,
    WHOLE,
    Origins,
    counted,
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
    "dot",  # one dot in the middle
    "dots_ring",  # dots around the object (one ring, or `layers` concentric rings of dots)
    "rings",  # concentric icing lines
    "dots_spiral",  # a ring of dots and a spiral inside
    "spiral",
    "star",
    "digits",
    "dot_per_slice",
    "free",  # the user leaves the design to the planner
]
DESIGNS: tuple[str, ...] = Design.__args__  # type: ignore[attr-defined]
CUT_DESIGNS = ("equal", "parallel", "width", "middle", "tips")
Orientation = Literal["vertical", "horizontal", "lengthwise", "crosswise"]
"""vertical/horizontal: along the object's own axis nearest the image's vertical/horizontal (a
round object's axes are the image's); lengthwise/crosswise: along or across its long axis."""
PieceShape = Literal["square", "wedge", "strip", "round"]
"""strip: a long piece (cuts run along the object's length); round: a disc cut across a long
object ("cucumber rounds")."""

CUT_VERBS = (
    r"\b(?:cut\w*|slic\w+|chop\w*|split\w*|divid\w+|halve\w*|quarter\w*|carv\w+|trim\w*|"
    r"portion\w*|wedges?|pieces?|parts?|tips?|ends?)\b"
)
STRONG_ICING = (
    r"\b(?:icing|icings|pip(?:e|es|ed|ing)|frost\w*|decorat\w*|dots?|rosettes?|draw|write)\b"
)


@dataclass(frozen=True)
class Intent:
    """What a sentence asks for: the family, the design and its numbers."""

    family: Family
    design: Design
    count: int | None = None
    """Parts, slices, dots (per ring), layers or star points, depending on the design."""
    slice_width_mm: float | None = None
    object_length_mm: float | None = None
    """A length the user states for the object (scales slice widths to the picture)."""
    orientation: Orientation | None = None
    text: str | None = None
    """Characters for the seven-segment design."""
    understood: tuple[str, ...] = field(default_factory=tuple)
    layers: int | None = None
    """Rings of dots (design dots_ring): how many concentric rings; None is one."""
    piece_shape: PieceShape | None = None
    """The shape the pieces must have ("9 squares", "8 wedges"), when the sentence says."""
    edge_distance_mm: float | None = None
    """Icing rings and rings of dots: how far in from the object's edge the (outer) ring runs
    ("dots half an inch from the edge"); None is the design's own spacing."""

    def describe(self) -> str:
        parts = [f"{self.family}: {self.design.replace('_', ' ')}"]
        if self.layers is not None:
            parts.append(f"{self.layers} rings")
        if self.count is not None:
            parts.append(f"count {self.count}")
        if self.piece_shape is not None:
            parts.append(f"{self.piece_shape} pieces")
        if self.slice_width_mm is not None:
            parts.append(f"slices {self.slice_width_mm / 10:g} cm wide")
        if self.object_length_mm is not None:
            parts.append(f"object {self.object_length_mm / 10:g} cm long")
        if self.edge_distance_mm is not None:
            parts.append(f"{self.edge_distance_mm / 10:g} cm from the edge")
        if self.orientation:
            parts.append(self.orientation)
        if self.text:
            parts.append(f"text {self.text!r}")
        return ", ".join(parts)

    @property
    def primitive_family(self) -> str:
        """The primitive family (keymps.primitives.dictionary.FAMILIES) this design needs."""
        return "cutting" if self.family == "cut" else "icing"


@dataclass
class _Reader:
    """A sentence being read, with the spans and words understood so far."""

    text: str
    understood: list[str] = field(default_factory=list)
    spans: list[tuple[int, int]] = field(default_factory=list)

    def find(self, pattern: str) -> re.Match[str] | None:
        """The first match, remembered as understood (its numbers are then attached)."""
        match = re.search(pattern, self.text)
        if match:
            self.take(match)
        return match

    def take(self, match: re.Match[str]) -> None:
        self.understood.append(match.group(0).strip())
        self.spans.append(match.span())

    def has(self, pattern: str) -> bool:
        return re.search(pattern, self.text) is not None

    def leftovers(self) -> list[str]:
        """Quantities of the sentence no understood phrase holds: numbers (with their unit)
        and units without a number."""
        loose = []
        for quantity in re.finditer(LEFTOVER, self.text):
            start, end = quantity.span()
            if not any(a <= start and end <= b for a, b in self.spans):
                loose.append(quantity.group(0).strip())
        return loose


LEFTOVER = rf"{LENGTH}|\d+(?:\.\d+)?|\b{LENGTH_UNITS}\b"
"""A quantity that must belong to an understood phrase: a length, a number, a unit."""


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


def _object_dimensions(reader: _Reader) -> None:
    """Other sizes of the object ("width 8 cm", "20 cm across"): read, not needed for a layout."""
    for pattern in (
        rf"\b(?:width|diameter|height|depth)\s+(?:of\s+|is\s+)?(?:about\s+)?{LENGTH}",
        rf"\b{LENGTH}\s+(?:across|in diameter|diameter|tall|high|deep)\b",
        rf"\b{LENGTH}\s*x\s*{LENGTH}",
    ):
        while (match := re.search(pattern, reader.text)) and match.span() not in reader.spans:
            reader.take(match)
            break


NOT_A_WIDTH = r"(?!\s+(?:(?:in|away)\s+)?(?:from|off)\b)"
"""After a length: it is a distance ("half an inch from the edge"), not a slice's width."""


def _slice_width(reader: _Reader) -> float | None:
    patterns = [
        rf"{LENGTH}\s+(?:thick\s+|wide\s+)?{PIECES}",
        rf"{PIECES}\s+(?:of\s+|about\s+|each\s+)*{LENGTH}{NOT_A_WIDTH}",
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


def _piece_shape(noun: str) -> PieceShape | None:
    if re.search(r"squares?\b", noun):
        return "square"
    if re.search(r"wedges?\b|triangles?\b", noun):
        return "wedge"
    if re.search(r"strips?\b", noun):
        return "strip"
    if re.search(r"(?:rounds?|coins?|discs?|disks?)\b", noun):
        return "round"
    return None


def _part_count(reader: _Reader) -> tuple[int | None, PieceShape | None]:
    """How many parts, slices or portions the sentence asks for (None if it does not say)."""
    if reader.find(
        r"\b(?:1 \w+ (?:for|per|a) )?(?:each|every)\s+day\s+(?:of\s+)?(?:this|the|a)\s+week\b"
    ):
        return 7, None
    if reader.find(r"\bfor (?:a|the|this) week\b|\b7 days\b"):
        return 7, None
    people = reader.find(counted(PEOPLE, 2)) or reader.find(rf"{COUNT} of us\b")
    reader.find(
        r"\b1\s+(?:\w+\s+)?(?:slice|piece|portion|wedge|serving)\s+(?:for\s+|to\s+)?"
        r"(?:each(?:\s+of\s+(?:them|us))?|apiece|per\s+(?:person|head|guest))\b"
    )
    if people:
        return int(people.group(1)), None
    match = re.search(
        rf"{COUNT}\s+(?:{NUMBER}\s*{UNIT_RE}\s+)?{FILLER}{{0,3}}({PIECES})", reader.text
    )
    followed = reader.text[match.end() :] if match else ""
    if match and not re.match(r"\s*(?:for|per)\s+(?:each|every)", followed):
        reader.take(match)
        return int(match.group(1)), _piece_shape(match.group(3))
    match = reader.find(
        rf"\b(?:into|in)\s+{COUNT}(?!\s*{UNIT_RE}\b)(?:\s+{FILLER}{{0,3}}({PIECES}))?"
    )
    if match:
        return int(match.group(1)), _piece_shape(match.group(2) or "")
    if reader.find(r"\bin half\b|\bhalve\b|\bin 2\b|\bhalves\b"):
        return 2, None
    if reader.find(r"\bin thirds\b|\binto thirds\b"):
        return 3, None
    if reader.find(r"\bquarters?\b|\bquarter it\b"):
        return 4, None
    return None, None


def _icing_intent(reader: _Reader) -> Intent | None:
    """The icing design the sentence asks for: the first of the designs, in this order, it names
    (each reader remembers the phrases it understood, even when it then declines)."""
    for read in (
        _dot_per_slice,
        _digits,
        _star,
        _spiral,
        _rings_of_dots,
        _rings,
        _middle_dot,
        _dots_ring,
        _free_design,
    ):
        intent = read(reader)
        if intent is not None:
            return intent
    return None


def _dots_around(reader: _Reader) -> bool:
    """Dots (or dots of icing) around, along the border, edge or rim, or in a circle or ring."""
    return reader.has(rf"\b{DOTS}\b|\bdots? of icing\b") and reader.has(
        r"\baround\b|\bborder\b|\bedge\b|\brim\b|\bcircle\b|\bring\b"
    )


def _dot_per_slice(reader: _Reader) -> Intent | None:
    match = reader.find(
        rf"\b(?:1|a|an) (?:\w+ )?(?:dot|drop|rosette|blob|dollop)s?\b.*\beach of (?:the )?{COUNT} "
        rf"{PIECES}"
    ) or reader.find(
        rf"\b(?:dot|rosette)s? (?:on|in) (?:the middle of )?each of (?:the )?{COUNT} {PIECES}"
    )
    return Intent("icing", "dot_per_slice", count=int(match.group(1))) if match else None


def _digits(reader: _Reader) -> Intent | None:
    match = reader.find(r"\b(\d+)(?:st|nd|rd|th) birthday\b") or reader.find(
        r"\b(?:digits?|numbers?|number|write|seven_segment\w*)\s+(?:of\s+|the\s+)?"
        r"(?:(?:number|digits?)\s+)?(\d+)\b"
    )
    if match and (reader.has(r"digit|seven_segment|number|write|birthday")):
        reader.find(r"\bseven_segment\b")
        return Intent("icing", "digits", text=match.group(1))
    return None


def _star(reader: _Reader) -> Intent | None:
    if not reader.has(r"\bstars?\b"):
        return None
    match = reader.find(rf"{COUNT}[- ]?(?:pointed|point|pointy)\s+star\b") or reader.find(
        rf"\bstar\s+with\s+{COUNT}\s+(?:points|tips|arms)\b"
    )
    count = int(match.group(1)) if match else 5
    if not match:
        reader.find(r"\b(?:a|an|1)\s+(?:\w+\s+){0,2}star\b|\bstar\b")
    return Intent("icing", "star", count=count)


def _spiral(reader: _Reader) -> Intent | None:
    if not reader.has(r"\bspiral|\bswirl"):
        return None
    reader.find(r"\bspiral\w*|\bswirl\w*")
    reader.find(r"\b2 (?:types?|kinds?|sorts?) of (?:designs?|patterns?)\b")
    if _dots_around(reader):
        reader.find(r"\bdots? around\b|\baround\b")
        return Intent("icing", "dots_spiral", count=_dot_count(reader))
    return Intent("icing", "spiral")


def _rings(reader: _Reader) -> Intent | None:
    match = reader.find(counted(r"(?:layers?|rings?|circles?|lines)\b"))
    if match and reader.has(r"\baround\b|\blayers?\b|\brings?\b|\bcircles?\b"):
        return Intent("icing", "rings", count=int(match.group(1)))
    if reader.has(r"\blayers?\b|\brings? of icing\b|\bicing (?:line|ring) around\b"):
        reader.find(r"\blayers?\b|\brings?\b|\bline\b")
        return Intent("icing", "rings", count=1)
    return None


def _middle_dot(reader: _Reader) -> Intent | None:
    """One dot in the middle; refuses N dots in the middle (neither design)."""
    middle = r"(?:in|on|at|into)\s+(?:the\s+)?(?:very\s+|exact\s+)?(?:middle|cent(?:re|er))"
    single = rf"\b(?:1|a|an)\s+{FILLER}{{0,2}}(?:dot|rosette|drop|blob|dollop|kiss)\b"
    if reader.find(rf"{single}(?:\s+of\s+\w+)?\s+(?:right\s+)?{middle}") or reader.find(
        rf"\b{middle}\b.*{single}"
    ):
        return Intent("icing", "dot", count=1)
    several = re.search(rf"{counted(DOTS)}(?:\s+of\s+\w+)?\s+{middle}", reader.text)
    if several and not _dots_around(reader):
        raise UnreadableInstruction(
            f"the offline planner puts 1 dot in the middle, or N dots around the object; "
            f"{several.group(0)!r} is neither (it never guesses). Ask for 'a dot in the middle' or "
            f"'{several.group(1)} dots around the cake', or {VLM_HINT}"
        )
    return None


def _dots_ring(reader: _Reader) -> Intent | None:
    dots_around = _dots_around(reader)
    if not (dots_around or reader.has(counted(DOTS))):
        return None
    reader.find(r"\baround\b|\bborder\b|\bedge\b")
    dots = _dot_count(reader)
    if dots == 1 and not dots_around:  # "pipe 1 dot": where one dot goes, the middle
        return Intent("icing", "dot", count=1)
    return Intent("icing", "dots_ring", count=dots)


def _free_design(reader: _Reader) -> Intent | None:
    if reader.find(
        r"\b(?:simple|interesting|any|nice|pretty|beautiful|creative|random|your own)\b.*\bdesign\b"
        r"|\bsurprise me\b|\bdecorate (?:it|the cake)\b"
    ):
        return Intent("icing", "free")
    return None


def _rings_of_dots(reader: _Reader) -> Intent | None:
    """ "3 rings of dots", "two circles of 12 rosettes", "dots in 3 rings", "a ring of dots"."""
    ring = r"(?:rings?|circles?|rows?|layers?)"
    match = reader.find(
        rf"\b({WHOLE}|a|an)\s+{FILLER}{{0,3}}{ring}\s+of\s+(?:({WHOLE})\s+)?{FILLER}{{0,2}}{DOTS}\b"
    ) or reader.find(rf"\b{DOTS}\s+(?:\w+\s+){{0,3}}?in\s+({WHOLE}|a)\s+{FILLER}{{0,2}}{ring}\b")
    if match is None:
        return None
    layers = int(match.group(1)) if match.group(1).isdigit() else 1
    per_ring = match.group(2) if match.lastindex and match.lastindex >= 2 else None
    if per_ring is None:
        each = reader.find(
            rf"{counted(DOTS)}\s+(?:each|per\s+(?:ring|circle|row)|in\s+each(?:\s+{ring})?)\b"
        ) or reader.find(rf"\b(?:each|every)\s+{ring}\s+(?:has|with|of)\s+{COUNT}")
        per_ring = each.group(1) if each else None
    if per_ring is None and layers == 1 and (total := reader.find(counted(DOTS))):
        per_ring = total.group(1)  # "15 dots in a circle"
    count = int(per_ring) if per_ring else None
    return Intent("icing", "dots_ring", count=count, layers=layers if layers > 1 else None)


def _dot_count(reader: _Reader) -> int | None:
    match = reader.find(counted(DOTS)) or reader.find(rf"{COUNT}\s+{DOTS}?\s*of icing\b")
    return int(match.group(1)) if match else None


def _cut_intent(reader: _Reader) -> Intent | None:
    trimmed = reader.find(
        rf"{LENGTH}\s+(?:off\s+(?:of\s+)?|from\s+|in\s+from\s+)(?:both|each|either|the 2|2)\s+"
        r"(?:tips?|ends?)\b"
    )
    if trimmed or reader.find(
        r"\b(?:both|2|the 2)\s+(?:tips|ends)\b|\b(?:tips|ends) off\b|\btop and tail\b"
    ):
        inset = _mm(trimmed.group(1), trimmed.group(2)) if trimmed else None
        return Intent("cut", "tips", slice_width_mm=inset, object_length_mm=_object_length(reader))
    width = _slice_width(reader)
    object_length = _object_length(reader)
    _object_dimensions(reader)
    orientation = _orientation(reader)
    if width is not None:
        counted_slices = reader.find(
            rf"{COUNT}\s+{FILLER}{{0,2}}(?:{NUMBER}\s*-?\s*{UNIT_RE}\s+)?{FILLER}{{0,2}}{PIECES}"
        )
        slice_count = int(counted_slices.group(1)) if counted_slices else None
        if slice_count is None and reader.find(
            rf"\b(?:a|an|1)\s+{LENGTH}\s+(?:thick\s+|wide\s+)?(?:slice|piece|strip)\b"
        ):
            slice_count = 1
        return Intent(
            "cut",
            "width",
            count=slice_count,
            slice_width_mm=width,
            object_length_mm=object_length,
            orientation=orientation,
            piece_shape=_piece_shape(" ".join(re.findall(PIECES, reader.text))),
        )
    count, shape = _part_count(reader)
    middle = reader.has(r"\b(?:middle|centre|center|half)\b")
    single = r"\b1 (?:\w+ )?(?:slice|cut)\b"
    if middle and (count in (None, 1) or reader.has(single)):
        reader.find(single)
        reader.find(r"\bmiddle\b|\bcent(?:re|er)\b|\bhalf\b")
        return Intent("cut", "middle", count=1, orientation=orientation)
    if count is not None and count >= 2:
        design: Design = "parallel" if orientation or shape == "strip" else "equal"
        return Intent("cut", design, count=count, orientation=orientation, piece_shape=shape)
    return None


def read_instruction(sentence: str) -> Intent:
    """The design the sentence asks for, or UnreadableInstruction saying what was understood."""
    origins: Origins = {}
    text = normalise(sentence, origins)
    vague = re.search(
        rf"\b(?:a few|several|some|many|a lot of|lots of|a number of)\s+(?:\w+\s+)?"
        rf"(?:{PIECES}|{DOTS}|rings?|layers?)",
        text,
    )
    if vague:
        raise UnreadableInstruction(
            unreadable_message(sentence, [f"{vague.group(0)!r} does not say how many"])
        )
    refuse_misspelled_counts(sentence, text)
    refuse_fractional_counts(sentence, text, origins)
    refuse_ambiguous_fractions(sentence, text)
    reader = _Reader(text)
    intent = _icing_intent(reader) if reader.has(ICING_WORDS) else None
    if intent is None:
        if reader.has(STRONG_ICING) and not reader.has(CUT_VERBS):
            refuse_unknown_design(sentence, text, "icing", reader.understood)
            raise UnreadableInstruction(unreadable_message(sentence, reader.understood))
        reader = _Reader(text)
        intent = _cut_intent(reader)
    family = intent.family if intent is not None else None
    refuse_unknown_design(sentence, text, family, reader.understood)
    if intent is None:
        raise UnreadableInstruction(unreadable_message(sentence, reader.understood))
    refuse_unmodelled(sentence, text, intent)
    if intent.family == "icing":
        refuse_second_design(sentence, text, intent)
        intent = _with_edge_distance(reader, intent, sentence, origins)
    loose = reader.leftovers()
    if loose:
        raise UnreadableInstruction(
            f"the offline planner read {sentence.strip()!r} as {intent.describe()}, but cannot "
            f"tell what {as_written(loose, origins)} refers to; it never guesses. "
            f"Rephrase (it reads {CAPABILITIES}), or {VLM_HINT}"
        )
    intent = replace(intent, understood=tuple(reader.understood))
    _check_numbers(intent)
    return intent


EDGE_DISTANCE = (
    rf"(?:\b(?:a|an)\s+)?{LENGTH}\s+(?:of\s+)?(?:(?:space|gap|room|margin)\s+)?(?:(?:in|away)\s+)?"
    r"(?:from|off|inside|in from)\s+(?:the\s+)?(?:[\w]+'s\s+|its\s+|cake\s+)?"
    r"(?:edges?|rims?|borders?|sides?|outside)\b"
    rf"|(?:\b(?:a|an|with)\s+)?{LENGTH}\s+(?:margin|border)\b"
)
"""'half an inch from the edge', '1 cm in from the rim', 'a 2 cm margin'."""
EDGE_DESIGNS = ("dots_ring", "rings", "dots_spiral", "free")


def _with_edge_distance(reader: _Reader, intent: Intent, sentence: str, origins: Origins) -> Intent:
    """The intent with the distance of its ring from the edge, when the sentence gives one."""
    match = reader.find(EDGE_DISTANCE)
    if match is None:
        return intent
    length, unit = (match.group(1), match.group(2)) if match.group(1) else match.group(3, 4)
    if intent.design not in EDGE_DESIGNS:
        raise UnreadableInstruction(
            f"the offline planner read {sentence.strip()!r} as {intent.describe()}, which is "
            f"laid out in the middle: it cannot follow {as_written([f'{length} {unit}'], origins)}"
            " from the edge (rings and rings of dots take a distance from the edge); it never "
            f"guesses. Rephrase, or {VLM_HINT}"
        )
    return replace(intent, edge_distance_mm=_mm(length, unit))


def sentence_family(sentence: str) -> Family | None:
    """'cut' or 'icing' when the sentence clearly asks for one tool family, else None.

    Used for every backend before planning: 'Put 10 icing dots around the bread' on a knife
    task stops there. Unclear sentences ('decorate the slices') decide nothing.
    """
    text = normalise(sentence)
    icing = re.search(STRONG_ICING, text) is not None
    cutting = re.search(r"\b(?:cut\w*|slic(?:e|es|ing)\b(?!\s+of)|chop\w*|halve|carv\w+)", text)
    if icing and not cutting:
        return "icing"
    if cutting and not icing:
        return "cut"
    return None


MAX_COUNT = 1000
"""The largest count the offline planner lays out (planner.max_pairs limits the plan anyway)."""


def _check_numbers(intent: Intent) -> None:
    for value in (intent.count, intent.layers):
        if value is not None and not 1 <= value <= MAX_COUNT:
            raise KeympsError(
                f"the offline planner read a count of {value} ({intent.describe()}); "
                f"it lays out 1 to {MAX_COUNT}"
            )
    for what, size in (
        ("slice width", intent.slice_width_mm),
        ("length", intent.object_length_mm),
    ):
        if size is not None and not 0.5 <= size <= 10_000:
            raise KeympsError(
                f"the offline planner read a {what} of {size:g} mm; it must be 0.5 mm to 10 m"
            )
    if intent.design == "star" and intent.count is not None and intent.count < 3:
        raise KeympsError(f"a star needs at least 3 points, not {intent.count}")
