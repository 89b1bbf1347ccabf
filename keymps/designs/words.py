"""The vocabulary of the offline planner's grammar: numbers as words, units, kitchen nouns."""

from __future__ import annotations

import re

from keymps.designs.quantities import (
    Origins,
    fraction_words,
    marks_and_symbols,
    spoken_numbers,
)

UNITS = {
    "mm": 1.0,
    "millimeter": 1.0,
    "millimeters": 1.0,
    "millimetre": 1.0,
    "millimetres": 1.0,
    "cm": 10.0,
    "centimeter": 10.0,
    "centimeters": 10.0,
    "centimetre": 10.0,
    "centimetres": 10.0,
    "m": 1000.0,
    "meter": 1000.0,
    "meters": 1000.0,
    "metre": 1000.0,
    "metres": 1000.0,
    "inch": 25.4,
    "inches": 25.4,
    "in": 25.4,
    "foot": 304.8,
    "feet": 304.8,
    "ft": 304.8,
}
ONES = [
    "zero",
    "one",
    "two",
    "three",
    "four",
    "five",
    "six",
    "seven",
    "eight",
    "nine",
    "ten",
    "eleven",
    "twelve",
    "thirteen",
    "fourteen",
    "fifteen",
    "sixteen",
    "seventeen",
    "eighteen",
    "nineteen",
]
TENS = {
    "twenty": 20,
    "thirty": 30,
    "forty": 40,
    "fifty": 50,
    "sixty": 60,
    "seventy": 70,
    "eighty": 80,
    "ninety": 90,
}
ORDINALS = {
    "first": 1,
    "second": 2,
    "third": 3,
    "fourth": 4,
    "fifth": 5,
    "sixth": 6,
    "seventh": 7,
    "eighth": 8,
    "ninth": 9,
    "tenth": 10,
}
NUMBER_WORDS = (*ONES, *TENS, "hundred", "dozen")
NEAR_NUMBER_WORDS = frozenset(
    {"even", "seen", "then", "there", "these", "tree", "trees", "teen", "bone", "done", "gone"}
    | {"lone", "none", "tone", "weight", "height", "freight", "leaven", "fifth", "sixth"}
)
"""English words as close to a number word as a typo is ('even' to 'seven'): never read as one."""
TYPO_SIMILARITY = 0.8
"""difflib's ratio from which a word is taken for a misspelled number word ('eigth', 'fiften',
'sevn', 'ninty' are 0.8-0.92); words under 4 letters are never (too many real words are near:
'for', 'our', 'to', 'on')."""


def misspelled_number(word: str) -> str | None:
    """The number word `word` looks like a typo of ('eigth' -> 'eight'), else None."""
    if len(word) < 4 or word in NEAR_NUMBER_WORDS or word in NUMBER_WORDS:
        return None
    import difflib  # (not imported by commands that read no sentence)

    close = difflib.get_close_matches(word, NUMBER_WORDS, n=1, cutoff=TYPO_SIMILARITY)
    return close[0] if close else None


PIECES = (
    r"(?:slices?|pieces?|parts?|portions?|wedges?|sections?|segments?|servings?|chunks?|"
    r"strips?|equal\s+parts?|triangles?|squares?|rounds?|coins?|discs?|disks?)"
)
PEOPLE = r"(?:people|persons?|guests?|friends?|kids?|children|adults?|visitors?|servings?)"
UNIT_RE = (
    r"(?:mm|cm|m|millimet(?:er|re)s?|centimet(?:er|re)s?|met(?:er|re)s?|inch(?:es)?|foot|feet|"
    r"ft|in(?=\s*-?\s*(?:thick|wide|long|apart|each|from|in from|away|margin|slices?|pieces?|"
    r"rounds?|coins?|strips?|chunks?|sections?)\b|\s*$))"
)
"""Length units; "in" only where no preposition can stand ("1 in slices", not "2 in half")."""
NUMBER = r"(?<![\d./])(\d+(?:\.\d+)?)"
LENGTH = rf"{NUMBER}\s*-?\s*({UNIT_RE})\b"
WHOLE = r"(?<![./])\d+(?![./]?\d)"
"""A whole number standing alone (not a part of '2.5')."""
COUNT = rf"\b({WHOLE})"
"""WHOLE as group 1, from a word boundary."""
DOTS = r"(?:dots?|icings|rosettes?|drops?|blobs?|dollops?|kisses)"
"""Nouns for one piped dot (start = end)."""
FILLER = (
    r"(?:(?!(?:of|and|or|with|for|per|each|every|in|on|into|around|at|to|the|a|an|it|this|"
    r"that|them|long|mm|cm|m|millimet(?:er|re)s?|centimet(?:er|re)s?|met(?:er|re)s?|inch(?:es)?|"
    r"foot|feet|ft|slices?|pieces?|parts?|rings?|layers?|circles?|rows?|is|are|was|be)\b)"
    r"[a-z][a-z'-]*\s+)"
)
"""One word that may stand between a count and its noun ("18 little dots", "3 neat rings")."""


def counted(noun: str, fillers: int = 3) -> str:
    """A count, up to `fillers` adjectives, then `noun`; the count is group 1."""
    return rf"{COUNT}\s+{FILLER}{{0,{fillers}}}{noun}"


ICING_WORDS = (
    r"\b(?:icing|icings|ice|dots?|rosettes?|decorat\w*|designs?|pip(?:e|ing)|frost\w*|cream|"
    r"stars?|spirals?|swirls?|layers?|rings?|circles?|digits?|seven_segment|birthday|"
    r"write|letters?|numbers?|rosettes?|drops?|blobs?|dollops?|pipe|draw|surprise)\b"
)


def words_to_digits(text: str) -> str:
    def compound(match: re.Match[str]) -> str:
        return str(TENS[match.group(1)] + ONES.index(match.group(2)))

    ones = "|".join(ONES[1:10])
    text = re.sub(rf"\b({'|'.join(TENS)})[- ]({ones})\b", compound, text)
    ordinal_ones = "|".join(list(ORDINALS)[:9])
    text = re.sub(
        rf"\b({'|'.join(TENS)})[- ]({ordinal_ones})\b",
        lambda m: f"{TENS[m.group(1)] + ORDINALS[m.group(2)]}th",
        text,
    )
    for word, value in TENS.items():
        text = re.sub(rf"\b{word}\b", str(value), text)
    for value, word in enumerate(ONES):
        text = re.sub(rf"\b{word}\b", str(value), text)
    for word, value in ORDINALS.items():
        text = re.sub(rf"\b{word}\b", f"{value}th", text)
    text = re.sub(r"\bhalf a dozen\b", "6", text)
    text = re.sub(r"\ba dozen\b|\bdozen\b", "12", text)
    text = re.sub(r"\b(?:a\s+)?single\b", "1", text)
    text = re.sub(r"\b(?:a\s+)?couple of\b", "2", text)
    return text


def normalise(sentence: str, origins: Origins | None = None) -> str:
    """Lower case, numbers as digits, quantities as decimals with units ("half an inch" is
    "0.5 inch"), no punctuation. `origins` collects the words each rewritten number was."""
    origins = {} if origins is None else origins
    text = sentence.lower().replace("’", "'").replace("×", "x")
    text = marks_and_symbols(text, origins)
    text = re.sub(r"[,;:!?()\[\]\"]", " ", text)
    text = re.sub(r"\.(?!\d)", " ", text)
    # "seven-segment" names the digit style, not a count (kept out of the number words)
    text = re.sub(r"\b(?:seven|7)[- ]?segments?\b", "seven_segment", text)
    text = fraction_words(text, origins)
    text = spoken_numbers(words_to_digits(text), origins)
    return re.sub(r"\s+", " ", text).strip()
