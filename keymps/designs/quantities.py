"""Spoken quantities as numbers: "half an inch", "1/2\"", "one and a half cm", "½", ".5 in".

The grammar reads lengths as a decimal number and a unit ("0.5 inch"). People write fractions
in words, with slashes, with an inch mark or a Unicode fraction; these functions rewrite each
form to that decimal, and remember what they rewrote, so that a refusal can quote the user's own
words ("half an inch") rather than the number it became. Fraction words become numbers only
where a unit follows ("half an inch", "a quarter-inch"): "cut it in half" stays a count.
"""

from __future__ import annotations

import re
from collections.abc import Callable

LENGTH_UNITS = (
    r"(?:mm|cm|millimet(?:er|re)s?|centimet(?:er|re)s?|met(?:er|re)s?|inch(?:es)?|foot|feet|ft)"
)
"""The units no other English word shares ("in" and "m" do: they need a number before them)."""
SEP = r"[\s-]+"
FRACTION_WORDS = {"half": 0.5, "quarter": 0.25, "third": 1 / 3}
UNICODE_FRACTIONS = {"½": "1/2", "¼": "1/4", "¾": "3/4", "⅓": "1/3", "⅔": "2/3", "⅛": "1/8"}
SMALL_WORDS = {"a": 1, "an": 1, "one": 1, "two": 2, "three": 3, "1": 1, "2": 2, "3": 3}
"""How many of a fraction word ("three quarters of an inch"), written out before words become
digits (the grammar's words_to_digits would read "third" as the ordinal "3th")."""

ONE_PIECE = r"(?:slice|piece|strip|round|chunk|section|portion|wedge|segment|stick|cube)"
"""A singular piece noun: the article before its length counts one ("an inch-thick slice")."""

Origins = dict[str, str]
"""Rewritten number (as it now stands in the text) -> the words it was written as."""


def number_text(value: float) -> str:
    """A decimal as the grammar reads it: '0.5', '1.5', '0.3333', '2'."""
    return f"{round(value, 4):g}"


def _rewrite(
    text: str, pattern: str, value: Callable[[re.Match[str]], str | None], origins: Origins
) -> str:
    """Replace each match by value(match) (None keeps it), remembering the original words."""

    def replace(match: re.Match[str]) -> str:
        new = value(match)
        if new is None:
            return match.group(0)
        numbers = re.findall(r"\d+(?:\.\d+)?", new)
        if numbers:  # the quantity's own number is the last one ("2 0.5 inch": 2 half-inches)
            old = match.group(0).strip()
            origins.setdefault(numbers[-1], origins.get(old, old))
        return new

    return re.sub(pattern, replace, text)


def marks_and_symbols(text: str, origins: Origins) -> str:
    """Inch marks (1/2"), Unicode fractions, decimal commas (1,5 cm) and leading points (.5):
    rewritten before the sentence's punctuation is dropped. Lower-case text."""
    for symbol, fraction in UNICODE_FRACTIONS.items():
        # glued to a whole number it is a mixed number: "3½" is "3-1/2", never "3 1/2"
        text = re.sub(rf"(\d){symbol}", rf"\1-{fraction}", text).replace(symbol, f" {fraction}")
    text = _inch_marks(text)
    text = re.sub(rf"(\d),(\d{{1,3}})(?=\s*{LENGTH_UNITS}\b)", r"\1.\2", text)
    return _rewrite(text, r"(?<![\d.])\.(\d+)", lambda m: f"0.{m.group(1)}", origins)


def _inch_marks(text: str) -> str:
    """A '"', '″' or "''" right after a number is inches, unless it closes a quotation."""
    out, last = [], 0
    for match in re.finditer(r"(?<=\d)(?:\"|″|'')", text):
        opened = text[: match.start()].count('"') % 2 == 1 and match.group(0) == '"'
        if opened:
            continue
        out.append(text[last : match.start()] + " inch ")
        last = match.end()
    out.append(text[last:])
    return "".join(out)


def fraction_words(text: str, origins: Origins) -> str:
    """'a third of an inch', 'three quarters of an inch', 'half a cm' (before number words
    become digits): each such fraction of a unit becomes its decimal. A number before a
    singular fraction counts pieces ("two half-inch slices"), and an article before one that a
    singular piece follows counts one ("a half-inch slice")."""
    pattern = (
        rf"\b(?:(a|an|one|two|three|1|2|3)({SEP}))?(half|halves|quarters?|thirds?){SEP}"
        rf"(?:of{SEP})?(?:(?:a|an){SEP})?({LENGTH_UNITS})\b(?=({SEP}(?:thick{SEP}|wide{SEP})?"
        rf"{ONE_PIECE}\b)?)"
    )

    def value(match: re.Match[str]) -> str | None:
        if re.search(rf"\band{SEP}$", match.string[: match.start()]):
            return None  # "one and a half inches": spoken_numbers reads the whole number
        before, joint, word, unit, one_piece = match.groups()
        fraction = FRACTION_WORDS[word.rstrip("s").replace("halve", "half")]
        times = SMALL_WORDS.get(before or "a", int(before) if (before or "").isdigit() else 1)
        if times > 1 and not (word.endswith("s") or joint == "-"):
            return f"{before} {number_text(fraction)} {unit}"  # a count of pieces
        count = "a " if one_piece and before in ("a", "an", "one", "1") else ""
        return f"{count}{number_text(times * fraction)} {unit}"

    return _rewrite(text, pattern, value, origins)


def spoken_numbers(text: str, origins: Origins) -> str:
    """After number words are digits: slashed fractions, 'N and a half', 'an inch and a half',
    'an inch' (1 inch), 'inch-thick' (1 inch thick)."""
    text = _rewrite(text, r"\b(?:(\d+)[\s-]+)?(\d+)/(\d+)\b", _slashed, origins)
    parts = r"(half|quarter|3 quarters?)"
    text = _rewrite(
        text,
        rf"\b(\d+(?:\.\d+)?){SEP}and{SEP}(?:an?{SEP})?{parts}\b",
        lambda m: number_text(float(m.group(1)) + _part(m.group(2))),
        origins,
    )
    text = _rewrite(
        text,
        rf"\b(an?|\d+(?:\.\d+)?){SEP}({LENGTH_UNITS}){SEP}and{SEP}an?{SEP}{parts}\b",
        lambda m: f"{number_text(_whole(m.group(1)) + _part(m.group(3)))} {m.group(2)}",
        origins,
    )
    text = _rewrite(
        text,
        rf"\b(?:an?){SEP}({LENGTH_UNITS})\b(?=({SEP}(?:thick{SEP}|wide{SEP})?{ONE_PIECE}\b)?)",
        lambda m: f"{'a ' if m.group(2) else ''}1 {m.group(1)}",
        origins,
    )
    text = re.sub(rf"\b({LENGTH_UNITS}|in)-(thick|wide|long)\b", r"\1 \2", text)
    return _rewrite(
        text,
        rf"(?<![\d.]\s)(?<![\d.]-)(?<![\d.])\b({LENGTH_UNITS}){SEP}(thick|wide)\b",
        lambda m: f"1 {m.group(1)} {m.group(2)}",
        origins,
    )


def _slashed(match: re.Match[str]) -> str | None:
    whole, top, bottom = match.group(1), int(match.group(2)), int(match.group(3))
    if bottom == 0 or ambiguous_mixed_number(match):
        return None
    return number_text((int(whole) if whole else 0) + top / bottom)


PLURAL_PIECES = (
    r"(?:slices|pieces|rounds|coins|discs|disks|chunks|strips|sticks|cubes|wedges|sections|"
    r"portions|segments|parts|dots|rosettes)"
)


def ambiguous_mixed_number(match: re.Match[str]) -> bool:
    """'3 1/2 cm slices' is 3 slices of 1/2 cm or slices of 3 1/2 cm: a whole number of 2 or
    more, a space, a fraction, a unit and pieces. '1 1/2 inch slices', '3-1/2 cm slices' and
    '3½ cm' are mixed numbers."""
    whole = match.group(1)
    if not whole or int(whole) < 2 or "-" in match.group(0):
        return False
    after = match.string[match.end() :]
    return (
        re.match(rf"\s*-?\s*(?:{LENGTH_UNITS}|in)\b(?:\s+\w+){{0,2}}?\s+{PLURAL_PIECES}", after)
        is not None
    )


def _part(words: str) -> float:
    return {"half": 0.5, "quarter": 0.25}.get(words, 0.75)


def _whole(word: str) -> float:
    return 1.0 if word in ("a", "an") else float(word)
