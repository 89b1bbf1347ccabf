"""What the offline planner refuses, and how it says so: one line naming the words.

A sentence it cannot read, a design it does not know (a heart, a flower ...), a word that changes
the design in a way no design models ("unequal", "the left half", "leaving the crust"), a count
that is no whole number, a mixed number that may be a count, two icing designs at once and a
quantity no phrase holds all raise UnreadableInstruction, which says what it understood and
what it can do. It never guesses.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from keymps.designs.words import (
    COUNT,
    DOTS,
    FILLER,
    PEOPLE,
    PIECES,
    UNIT_RE,
    Origins,
    misspelled_number,
)
from keymps.errors import KeympsError

if TYPE_CHECKING:
    from keymps.designs.grammar import Intent

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
UNMODELLED_CUT = (
    (
        r"\b(?:leav\w*|keep\w*|spar\w*|sav(?:e|es|ing)|avoid\w*|skip\w*|preserv\w*|"
        r"stop\w* (?:at|before)|short of)\s+(?:\w+\s+){0,2}?(?:crusts?|rims?|edges?|borders?|"
        r"skin|peel|rind|stems?|caps?|core|cent(?:re|er)|middle|bottom|base|ends?|tips?|bones?)\b",
        "a part of the object left uncut: every cut here runs across the whole object",
    ),
)
"""UNMODELLED's words for cuts only (icing "leaves space from the edge")."""


class UnreadableInstruction(KeympsError):
    """The offline planner cannot turn the sentence into a design."""


def as_written(quantities: list[str], origins: Origins) -> str:
    """The quantities quoted as the sentence wrote them ("half an inch", not "0.5 inch")."""
    quoted = []
    for quantity in quantities:
        number = quantity.split()[0] if quantity[:1].isdigit() else ""
        written = origins.get(re.sub(r"[^\d.]+$", "", number), "")
        quoted.append(repr(written if written and number else quantity))
    return ", ".join(quoted)


FRACTIONAL_COUNT = (
    rf"(?<![\d.])(\d+\.\d+)\s+(?:{FILLER}{{0,3}}(?:{PIECES}|{DOTS}|{PEOPLE}|rings?|layers?|"
    r"circles?|rows?|stars?|points?|cuts?|lines?)\b|(?=$))|\b(?:into|in)\s+(\d+\.\d+)\b"
    rf"(?!\s*-?\s*{UNIT_RE}\b)"
)
"""A number with a fraction where a count goes ("2.5 dots", "into 1.5")."""


def refuse_fractional_counts(sentence: str, text: str, origins: Origins) -> None:
    """A count is a whole number: '2.5 dots' is refused, not read as '5 dots' or 2 dots."""
    match = re.search(FRACTIONAL_COUNT, text)
    if match is None:
        return
    number = match.group(1) or match.group(2)
    written = origins.get(number, number)
    raise UnreadableInstruction(
        f"the offline planner found {written!r} where {sentence.strip()!r} gives a count, and "
        "a count is a whole number; it never rounds one. Ask for a whole number (a length "
        "needs its unit: '2.5 cm slices')"
    )


def refuse_ambiguous_fractions(sentence: str, text: str) -> None:
    """'3 1/2 cm slices' (a mixed number the quantities left as written: pieces follow)."""
    match = re.search(rf"(?<![\d.])(\d+) (\d+)/(\d+)\s*-?\s*({UNIT_RE})?", text)
    if match is None:
        return
    whole, top, bottom, unit = match.groups()
    unit = f" {unit}" if unit else ""
    raise UnreadableInstruction(
        f"the offline planner cannot tell whether {match.group(0).strip()!r} in "
        f"{sentence.strip()!r} is {whole} pieces {top}/{bottom}{unit} wide or pieces "
        f"{whole} {top}/{bottom}{unit} wide; it never guesses. Write '{whole} slices of "
        f"{top}/{bottom}{unit}', or '{whole}-{top}/{bottom}{unit} slices'"
    )


SECOND_DESIGNS = {
    "dots_ring": rf"\b(?:{COUNT}\s+)?(?:{FILLER}{{0,2}})(?:dots|icings|rosettes|drops|blobs|"
    r"dollops|kisses)\b(?:\s+[\w']+){0,4}?\s+(?:around|along the (?:edge|border|rim))\b",
    "dot": r"\b(?:1|a|an)\s+(?:\w+\s+){0,2}?(?:dot|rosette|drop|blob|dollop|kiss)\s+"
    r"(?:of \w+\s+)?(?:right\s+)?(?:in|on|at)\s+the\s+(?:very\s+|exact\s+)?(?:middle|cent(?:re|er))"
    r"\b(?! of each)",
    "star": r"\b(?:\d+[- ]?pointed\s+)?stars?\b",
    "spiral": r"\bspirals?\b|\bswirls?\b",
    "rings": r"\b(?:\d+\s+)?(?:layers?|rings?|circles?) of icing\b|\bicing (?:line|ring)s? around\b",
    "digits": r"\b\d+(?:st|nd|rd|th) birthday\b|\bdigits?\b",
}
"""Phrases of the icing designs: a sentence with two of them asks for two designs."""
COVERS = {
    "dots_spiral": ("dots_ring", "spiral"),
    "dot_per_slice": ("dot",),
    "free": ("dots_ring", "star"),
}
"""Designs that are already two phrases' designs."""


def refuse_second_design(sentence: str, text: str, intent: Intent) -> None:
    """'12 dots around the cake and a dot in the middle' asks for two designs: refused as
    such, never read as one of them with the other's number left over."""
    covered = {intent.design, *COVERS.get(intent.design, ())}
    if intent.design == "dots_ring":
        covered.add("rings")  # "3 rings of dots"
    found = [
        (m.start(), m.group(0).strip())
        for name, pattern in SECOND_DESIGNS.items()
        if name not in covered and (m := re.search(pattern, text))
    ]
    if not found:
        return
    own = [
        m.group(0).strip()
        for name, pattern in SECOND_DESIGNS.items()
        if name in covered and (m := re.search(pattern, text))
    ]
    phrases = sorted(found) if not own else [(0, own[0]), *sorted(found)]
    listed = " and ".join(repr(phrase) for _, phrase in phrases[:3])
    raise UnreadableInstruction(
        f"the offline planner lays out one icing design per object, and {sentence.strip()!r} "
        f"asks for {listed}; the one combination it has is dots around and a spiral. Ask for "
        f"one design, or {VLM_HINT}"
    )


COUNTED_NOUN = (
    rf"((?:\b[a-z][a-z'-]*\s+){{1,4}})(?:{PIECES}|{DOTS}|rings?|layers?|circles?|rows?)\b"
)
"""Up to four words before a noun that takes a count: where a misspelled count would be."""


def refuse_misspelled_counts(sentence: str, text: str) -> None:
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


def refuse_unmodelled(sentence: str, text: str, intent: Intent) -> None:
    own = UNMODELLED_ICING if intent.family == "icing" else UNMODELLED_CUT
    for pattern, what in UNMODELLED + own:
        match = re.search(pattern, text)
        if match:
            raise UnreadableInstruction(
                f"the offline planner read {sentence.strip()!r} as {intent.describe()}, but "
                f"cannot follow {match.group(0).strip()!r} ({what}); it never guesses. Rephrase "
                f"(it reads {CAPABILITIES}), or {VLM_HINT}"
            )


def refuse_unknown_design(
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
