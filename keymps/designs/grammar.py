"""The offline planner's instruction grammar: a sentence to a design intent, deterministically.

It reads counts (digits or words, wherever they stand: "eighteen little dots"), lengths (mm, cm,
m, inches), directions (vertically, horizontally, lengthwise, crosswise), and the kitchen
phrases of the KeyMPs paper's cases ("N people", "each day of this week", "both tips", "around",
"layers", "spiral", "N-pointed star", "27th birthday", "each of the N slices" ...).

It never guesses. A sentence it cannot read, a design it does not know (a heart, a flower ...)
and a number it cannot attach to the design all raise UnreadableInstruction, which says what it
did understand and what it can do.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import Literal

from keymps.designs.words import (
    DOTS,
    FILLER,
    ICING_WORDS,
    LENGTH,
    NUMBER,
    PEOPLE,
    PIECES,
    UNIT_RE,
    UNITS,
    counted,
    misspelled_number,
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
PieceShape = Literal["square", "wedge"]

CAPABILITIES = (
    "for cutting: N equal parts ('into 8 equal slices', 'for 10 people', 'each day of this "
    "week'), N parts vertically/horizontally, slices N cm wide, one cut through the middle, both "
    "tips; for icing: N dots around, N rings of dots, N rings of icing, a spiral, dots around and "
    "a spiral, an N-pointed star, digits ('27th birthday'), a dot on each of N slices, one dot "
    "in the middle, a free design"
)
VLM_HINT = "plan with a VLM: --model openai/gpt-4o (or any litellm model; see docs/vlm.md)"

UNKNOWN_DESIGNS = (
    r"\b(hearts?|flowers?|petals?|roses?|daisy|daisies|tulips?|logos?|faces?|smiley\w*|emojis?|"
    r"trees?|snowflakes?|butterfl(?:y|ies)|animals?|cats?|dogs?|bears?|bunn(?:y|ies)|rabbits?|"
    r"fish|birds?|leaf|leaves|moons?|crescents?|suns?|arrows?|zig-?zags?|waves?|wavy|"
    r"checker\w*|chessboard|lattice|cross(?:es)?|crown|balloons?|rainbows?|pictures?|portraits?|"
    r"drawings?|cartoons?|initials|monograms?|signatures?|skulls?|ghosts?|spider\w*|paws?|"
    r"diamonds?|hexagons?|pentagons?|octagons?|ovals?|ellipses?|polka|stripes?|plaid|"
    r"swirly|scallop\w*|ruffles?|shells?|borders? of lines|cubes?|dice|diced|julienne\w*|"
    r"sticks?|batons?|chips|fries|wedges? of lemon)\b"
)
"""Designs people ask for that the offline planner does not lay out (it refuses, never guesses)."""
UNKNOWN_ICING_SHAPES = r"\b(?:a|an|1)\s+(triangles?|squares?|rectangles?|letters?|x)\b"
"""Shapes that are pieces when cutting but unknown drawings when icing."""
WRITING = r"\b(?:spell|letters?|words?|names?|message|text|happy birthday|initials)\b"
CUT_VERBS = (
    r"\b(?:cut\w*|slic\w+|chop\w*|split\w*|divid\w+|halve\w*|quarter\w*|carv\w+|trim\w*|"
    r"portion\w*|wedges?|pieces?|parts?|tips?|ends?)\b"
)
UNMODELLED = (
    (
        r"\b(?:not|don't|dont|do not|never|without|except|instead of)\b",
        "a negation or an exception",
    ),
    (
        r"\b(?:unequal\w*|uneven\w*|irregular\w*|different[- ]sized|of different sizes|"
        r"varying|various sizes)\b",
        "parts of different sizes",
    ),
    (
        r"\b(?:left|right|top|bottom|upper|lower|front|back|other)\s+"
        r"(?:half|halves|side|part|third|quarter|corner|end|portion)\b|"
        r"\b(?:one|1)\s+(?:half|side|third|quarter|corner)\b|\bhalf of\b|\bcorners?\b",
        "a design on part of the object",
    ),
    (r"(?<![\w.])-\s?\d", "a negative number"),
    (
        r"\b(?:twice|thrice|again|then|after that|afterwards|followed by)\b|"
        r"\beach (?:of them|one|half|quarter|third|piece|slice|part|wedge)\b",
        "a second step or a repeat: each design here is one step",
    ),
    (
        r"\bdiagonal\w*|\bfrom the (?:left|right|top|bottom|outside|inside|far end|other end)\b|"
        r"\b(?:outside in|inside out|outside to the inside|inside to the outside)\b",
        "a direction or a starting side the designs do not take",
    ),
)
"""Words that change what a sentence asks for in ways no design here models: anywhere in the
sentence, they stop the plan instead of being skipped ("8 unequal slices" is not 8 equal ones,
"the left half" is not the whole cake; "cut it in half" is a design and matches none)."""
UNMODELLED_ICING = (
    (
        r"\bin an? (?:straight |neat )?(?:row|line|column|grid|cross|square|triangle|zigzag|wave)s?\b|"
        r"\b(?:along|across|through|down) the (?:middle|centre|center|diameter|length|width)\b",
        "a layout the icing designs do not have: they are rings, a centre dot, spirals and digits",
    ),
    (
        r"\b(?:outside|beyond|off) (?:of )?the (?:cake|object|edge|rim|top)\b|\bon the board\b",
        "a place off the object",
    ),
)
"""UNMODELLED's words for icing only ("along the border" is the ring; cuts go "along its
length" and "across")."""
STRONG_ICING = (
    r"\b(?:icing|icings|pip(?:e|es|ed|ing)|frost\w*|decorat\w*|dots?|rosettes?|draw|write)\b"
)


class UnreadableInstruction(KeympsError):
    """The offline planner cannot turn the sentence into a design."""


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

    def unattached_numbers(self) -> list[str]:
        """Numbers of the sentence that no understood phrase holds."""
        loose = []
        for number in re.finditer(r"\d+(?:\.\d+)?", self.text):
            start, end = number.span()
            if not any(a <= start and end <= b for a, b in self.spans):
                loose.append(number.group(0))
        return loose


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


def _piece_shape(noun: str) -> PieceShape | None:
    if re.search(r"squares?\b", noun):
        return "square"
    if re.search(r"wedges?\b|triangles?\b", noun):
        return "wedge"
    return None


def _part_count(reader: _Reader) -> tuple[int | None, PieceShape | None]:
    """How many parts, slices or portions the sentence asks for (None if it does not say)."""
    if reader.find(
        r"\b(?:1 \w+ (?:for|per|a) )?(?:each|every)\s+day\s+(?:of\s+)?(?:this|the|a)\s+week\b"
    ):
        return 7, None
    if reader.find(r"\bfor (?:a|the|this) week\b|\b7 days\b"):
        return 7, None
    people = reader.find(counted(PEOPLE, 2)) or reader.find(r"\b(\d+) of us\b")
    reader.find(
        r"\b1\s+(?:\w+\s+)?(?:slice|piece|portion|wedge|serving)\s+(?:for\s+|to\s+)?"
        r"(?:each(?:\s+of\s+(?:them|us))?|apiece|per\s+(?:person|head|guest))\b"
    )
    if people:
        return int(people.group(1)), None
    match = re.search(
        rf"\b(\d+)\s+(?:{NUMBER}\s*{UNIT_RE}\s+)?{FILLER}{{0,3}}({PIECES})", reader.text
    )
    followed = reader.text[match.end() :] if match else ""
    if match and not re.match(r"\s*(?:for|per)\s+(?:each|every)", followed):
        reader.take(match)
        return int(match.group(1)), _piece_shape(match.group(3))
    match = reader.find(
        rf"\b(?:into|in)\s+(\d+)\b(?!\s*(?:\.\d)?\s*{UNIT_RE}\b)(?:\s+{FILLER}{{0,3}}({PIECES}))?"
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
    match = reader.find(
        rf"\b(?:1|a|an) (?:\w+ )?(?:dot|drop|rosette|blob|dollop)s?\b.*\beach of (?:the )?(\d+) "
        rf"{PIECES}"
    ) or reader.find(
        rf"\b(?:dot|rosette)s? (?:on|in) (?:the middle of )?each of (?:the )?(\d+) {PIECES}"
    )
    if match:
        return Intent("icing", "dot_per_slice", count=int(match.group(1)))
    match = reader.find(r"\b(\d+)(?:st|nd|rd|th) birthday\b") or reader.find(
        r"\b(?:digits?|numbers?|number|write|seven_segment\w*)\s+(?:of\s+|the\s+)?"
        r"(?:(?:number|digits?)\s+)?(\d+)\b"
    )
    if match and (reader.has(r"digit|seven_segment|number|write|birthday")):
        reader.find(r"\bseven_segment\b")
        return Intent("icing", "digits", text=match.group(1))
    if reader.has(r"\bstars?\b"):
        match = reader.find(r"\b(\d+)[- ]?(?:pointed|point|pointy)\s+star\b") or reader.find(
            r"\bstar\s+with\s+(\d+)\s+(?:points|tips|arms)\b"
        )
        count = int(match.group(1)) if match else 5
        if not match:
            reader.find(r"\b(?:a|an|1)\s+(?:\w+\s+){0,2}star\b|\bstar\b")
        return Intent("icing", "star", count=count)
    dots_around = reader.has(rf"\b{DOTS}\b|\bdots? of icing\b") and reader.has(
        r"\baround\b|\bborder\b|\bedge\b|\brim\b|\bcircle\b|\bring\b"
    )
    if reader.has(r"\bspiral|\bswirl"):
        reader.find(r"\bspiral\w*|\bswirl\w*")
        reader.find(r"\b2 (?:types?|kinds?|sorts?) of (?:designs?|patterns?)\b")
        if dots_around:
            reader.find(r"\bdots? around\b|\baround\b")
            return Intent("icing", "dots_spiral", count=_dot_count(reader))
        return Intent("icing", "spiral")
    rings = _rings_of_dots(reader)
    if rings is not None:
        return rings
    match = reader.find(counted(r"(?:layers?|rings?|circles?|lines)\b"))
    if match and reader.has(r"\baround\b|\blayers?\b|\brings?\b|\bcircles?\b"):
        return Intent("icing", "rings", count=int(match.group(1)))
    if reader.has(r"\blayers?\b|\brings? of icing\b|\bicing (?:line|ring) around\b"):
        reader.find(r"\blayers?\b|\brings?\b|\bline\b")
        return Intent("icing", "rings", count=1)
    middle = r"(?:in|on|at|into)\s+(?:the\s+)?(?:very\s+|exact\s+)?(?:middle|cent(?:re|er))"
    single = rf"\b(?:1|a|an)\s+{FILLER}{{0,2}}(?:dot|rosette|drop|blob|dollop|kiss)\b"
    if reader.find(rf"{single}(?:\s+of\s+\w+)?\s+(?:right\s+)?{middle}") or reader.find(
        rf"\b{middle}\b.*{single}"
    ):
        return Intent("icing", "dot", count=1)
    several = re.search(rf"{counted(DOTS)}(?:\s+of\s+\w+)?\s+{middle}", reader.text)
    if several and not dots_around:
        raise UnreadableInstruction(
            f"the offline planner puts 1 dot in the middle, or N dots around the object; "
            f"{several.group(0)!r} is neither (it never guesses). Ask for 'a dot in the middle' or "
            f"'{several.group(1)} dots around the cake', or {VLM_HINT}"
        )
    if dots_around or reader.has(counted(DOTS)):
        reader.find(r"\baround\b|\bborder\b|\bedge\b")
        dots = _dot_count(reader)
        if dots == 1 and not dots_around:  # "pipe 1 dot": where one dot goes, the middle
            return Intent("icing", "dot", count=1)
        return Intent("icing", "dots_ring", count=dots)
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
        rf"\b(\d+|a|an|1)\s+{FILLER}{{0,3}}{ring}\s+of\s+(?:(\d+)\s+)?{FILLER}{{0,2}}{DOTS}\b"
    ) or reader.find(rf"\b{DOTS}\s+(?:\w+\s+){{0,3}}?in\s+(\d+|a|1)\s+{FILLER}{{0,2}}{ring}\b")
    if match is None:
        return None
    layers = int(match.group(1)) if match.group(1).isdigit() else 1
    per_ring = match.group(2) if match.lastindex and match.lastindex >= 2 else None
    if per_ring is None:
        each = reader.find(
            rf"{counted(DOTS)}\s+(?:each|per\s+(?:ring|circle|row)|in\s+each(?:\s+{ring})?)\b"
        ) or reader.find(rf"\b(?:each|every)\s+{ring}\s+(?:has|with|of)\s+(\d+)\b")
        per_ring = each.group(1) if each else None
    if per_ring is None and layers == 1 and (total := reader.find(counted(DOTS))):
        per_ring = total.group(1)  # "15 dots in a circle"
    count = int(per_ring) if per_ring else None
    return Intent("icing", "dots_ring", count=count, layers=layers if layers > 1 else None)


def _dot_count(reader: _Reader) -> int | None:
    match = reader.find(counted(DOTS)) or reader.find(rf"\b(\d+)\s+{DOTS}?\s*of icing\b")
    return int(match.group(1)) if match else None


def _cut_intent(reader: _Reader) -> Intent | None:
    if reader.find(r"\b(?:both|2|the 2)\s+(?:tips|ends)\b|\b(?:tips|ends) off\b|\btop and tail\b"):
        return Intent("cut", "tips")
    width = _slice_width(reader)
    object_length = _object_length(reader)
    _object_dimensions(reader)
    orientation = _orientation(reader)
    if width is not None:
        counted_slices = reader.find(
            rf"\b(\d+)\s+{FILLER}{{0,2}}(?:{NUMBER}\s*-?\s*{UNIT_RE}\s+)?{FILLER}{{0,2}}{PIECES}"
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
        )
    count, shape = _part_count(reader)
    middle = reader.has(r"\b(?:middle|centre|center|half)\b")
    single = r"\b1 (?:\w+ )?(?:slice|cut)\b"
    if middle and (count in (None, 1) or reader.has(single)):
        reader.find(single)
        reader.find(r"\bmiddle\b|\bcent(?:re|er)\b|\bhalf\b")
        return Intent("cut", "middle", count=1, orientation=orientation)
    if count is not None and count >= 2:
        design: Design = "parallel" if orientation else "equal"
        return Intent("cut", design, count=count, orientation=orientation, piece_shape=shape)
    return None


def read_instruction(sentence: str) -> Intent:
    """The design the sentence asks for, or UnreadableInstruction saying what was understood."""
    text = normalise(sentence)
    vague = re.search(
        rf"\b(?:a few|several|some|many|a lot of|lots of|a number of)\s+(?:\w+\s+)?"
        rf"(?:{PIECES}|{DOTS}|rings?|layers?)",
        text,
    )
    if vague:
        raise UnreadableInstruction(
            unreadable_message(sentence, [f"{vague.group(0)!r} does not say how many"])
        )
    _refuse_misspelled_counts(sentence, text)
    reader = _Reader(text)
    intent = _icing_intent(reader) if reader.has(ICING_WORDS) else None
    if intent is None:
        if reader.has(STRONG_ICING) and not reader.has(CUT_VERBS):
            _refuse_unknown_design(sentence, text, "icing", reader.understood)
            raise UnreadableInstruction(unreadable_message(sentence, reader.understood))
        reader = _Reader(text)
        intent = _cut_intent(reader)
    family = intent.family if intent is not None else None
    _refuse_unknown_design(sentence, text, family, reader.understood)
    if intent is None:
        raise UnreadableInstruction(unreadable_message(sentence, reader.understood))
    _refuse_unmodelled(sentence, text, intent)
    loose = reader.unattached_numbers()
    if loose:
        raise UnreadableInstruction(
            f"the offline planner read {sentence.strip()!r} as {intent.describe()}, but cannot "
            f"tell what {', '.join(repr(n) for n in loose)} refers to; it never guesses. "
            f"Rephrase (it reads {CAPABILITIES}), or {VLM_HINT}"
        )
    intent = replace(intent, understood=tuple(reader.understood))
    _check_numbers(intent)
    return intent


COUNTED_NOUN = (
    rf"((?:\b[a-z][a-z'-]*\s+){{1,4}})(?:{PIECES}|{DOTS}|rings?|layers?|circles?|rows?)\b"
)
"""Up to four words before a noun that takes a count: where a misspelled count would be."""


def _refuse_misspelled_counts(sentence: str, text: str) -> None:
    """A typo of a number word ('eigth dots') is no count: without this the design's default
    count was used, a confident wrong motion. Number words are digits in `text` by now."""
    for match in re.finditer(COUNTED_NOUN, text):
        for word in match.group(1).split():
            number = misspelled_number(word)
            if number:
                raise UnreadableInstruction(
                    f"the offline planner found {word!r} where {sentence.strip()!r} gives a "
                    f"count, and it is no number it knows (did you mean {number!r}?); it never "
                    f"guesses a count. Write the number in digits (8) or in words (eight)"
                )


def _refuse_unmodelled(sentence: str, text: str, intent: Intent) -> None:
    for pattern, what in UNMODELLED + (UNMODELLED_ICING if intent.family == "icing" else ()):
        match = re.search(pattern, text)
        if match:
            raise UnreadableInstruction(
                f"the offline planner read {sentence.strip()!r} as {intent.describe()}, but "
                f"cannot follow {match.group(0).strip()!r} ({what}); it never guesses. Rephrase "
                f"(it reads {CAPABILITIES}), or {VLM_HINT}"
            )


def _refuse_unknown_design(
    sentence: str, text: str, family: str | None, understood: list[str]
) -> None:
    unknown = re.search(UNKNOWN_DESIGNS, text)
    if unknown is None and family == "icing":
        unknown = re.search(UNKNOWN_ICING_SHAPES, text)
        if unknown is None and re.search(WRITING, text) and not re.search(r"\d", text):
            unknown = re.search(WRITING, text)
    if unknown is None:
        return
    word = unknown.group(unknown.lastindex or 0)
    seen = f"understood: {', '.join(repr(u) for u in understood)}; " if understood else ""
    raise UnreadableInstruction(
        f"the offline planner has no design for {word!r} in {sentence.strip()!r} ({seen}it never "
        f"guesses). It lays out {CAPABILITIES}. For anything else, {VLM_HINT}"
    )


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


def unreadable_message(sentence: str, understood: list[str]) -> str:
    seen = (
        f"understood only: {', '.join(repr(u) for u in understood)}"
        if understood
        else ("understood nothing it can build")
    )
    return (
        f"the offline planner cannot turn {sentence.strip()!r} into a design ({seen}). It reads "
        f"{CAPABILITIES}. Rephrase, or {VLM_HINT}"
    )
