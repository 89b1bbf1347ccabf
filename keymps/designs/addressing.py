"""Which object each part of a sentence is about: "each of them", "the left one", "the banana".

split_by_object turns a sentence and the scene's objects into clauses, each with the design
words for the grammar (keymps.designs.grammar reads them) and the ids of the objects it applies
to: "cut the left one in half and the right one into 4" gives ("cut it in half", [1]) and
("it into 4", [2]). The phrases read:

- all objects: each (of them, one, loaf ...), every, both, all, them, the two/3 ...;
- by place: the left/right/top/bottom/middle one (or ...most, or "the one on the left");
- by size: the largest/biggest/smallest/longest/shortest one (or larger/smaller of two);
- by name (scene.objects): the banana, the cakes, both cakes, the left cake;
- by number: object 2, #2, the 2nd one; "the other one(s)": those no earlier clause took.

With one object the sentence is its clause, word for word (single-object planning is exactly
what it always was). A sentence that names no object applies to the largest object when every other
is under half its area (crumbs, a garnish); with several objects of comparable size it is
refused, since guessing which one is meant is worse than asking.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from keymps.designs.words import words_to_digits
from keymps.errors import KeympsError

COMPARABLE = 0.5
"""Another object at least this fraction of the largest one's area makes "it" ambiguous."""
TIE = 0.25
"""Place and size words need the chosen object ahead of the next by this fraction (of the
smaller object's width, or of its area)."""

ONE = r"(?:one|1|object|item|piece of food)"
_GROUP_EXCLUDED = re.compile(
    r"\s+(?:of\s+(?:the\s+|these\s+|those\s+|its\s+)?)?(?:\d+\s+)?(?:slices?|pieces?|parts?|"
    r"portions?|wedges?|sections?|segments?|servings?|chunks?|strips?|days?|tips?|ends?|"
    r"sides?|halves|around|over|the way|guests?|people|persons?|week|dots?|layers?|rings?|"
    r"lines?|cuts?)\b"
)
"""Words after each/both/all that make it the grammar's (each of the 10 slices, both tips)."""
_CONJUNCTION = re.compile(
    r"\s*(?:,|;|\.(?!\d))?\s*\b(?:and then|and|then|but|while|plus)\b\s*|\s*[,;]\s*"
)


class AddressingError(KeympsError):
    """The sentence does not say which object (or names one that is not there)."""


@dataclass(frozen=True)
class Target:
    """An object as the sentence may address it."""

    id: int
    name: str | None
    centre: tuple[float, float]
    """Box centre, image pixels (x right, y down)."""
    size: tuple[float, float]
    """Box width and height, pixels."""
    area: float

    @property
    def label(self) -> str:
        return f"#{self.id} {self.name}" if self.name else f"#{self.id}"


@dataclass(frozen=True)
class Clause:
    """One part of a sentence and the objects it is about."""

    text: str
    """The design words, the object phrase replaced by 'it' (what the grammar reads)."""
    objects: tuple[int, ...]
    reference: str = ""
    """The words that chose the objects ('' when the sentence names none)."""


@dataclass(frozen=True)
class _Mention:
    """Words of a sentence that name objects, and which ones."""

    start: int
    end: int
    phrase: str
    objects: tuple[int, ...] | None
    """None for 'the other one(s)': resolved against the earlier clauses."""


def split_by_object(sentence: str, targets: list[Target]) -> list[Clause]:
    """The sentence's clauses, each with the objects it applies to; AddressingError if unclear."""
    if not targets:
        raise AddressingError("there is no object to plan on")
    text = words_to_digits(sentence.lower().replace("’", "'"))
    _refuse_absent_foods(text, targets)
    if len(targets) == 1:  # one object: the sentence is about it, word for word as always
        return [Clause(sentence, (targets[0].id,))]
    mentions = _mentions(text, targets)
    if not mentions:
        return [Clause(sentence, _default(targets))]
    pieces = _split(text, mentions)
    clauses: list[Clause] = []
    taken: set[int] = set()
    for mention, piece in zip(mentions, pieces, strict=True):
        objects = mention.objects
        if objects is None:
            objects = tuple(t.id for t in targets if t.id not in taken)
            if not objects:
                raise AddressingError(
                    f"{mention.phrase!r}: every object is already taken by the sentence"
                )
        taken.update(objects)
        clauses.append(Clause(piece, objects, mention.phrase))
    return clauses


def _default(targets: list[Target]) -> tuple[int, ...]:
    if len(targets) == 1:
        return (targets[0].id,)
    largest = max(targets, key=lambda t: t.area)
    rivals = [t for t in targets if t is not largest and t.area >= COMPARABLE * largest.area]
    if not rivals:
        return (largest.id,)
    first = _place_words(targets)[0]
    raise AddressingError(
        f"the scene has {len(targets)} objects ({_listed(targets)}) and the sentence does not "
        f"say which to work on: say 'each of them', 'both', 'the {first} one', 'the largest one'"
        + (
            ", or an object's name"
            if any(t.name for t in targets)
            else ", or name them in scene.objects to say 'the banana'"
        )
        + " (or keep one object with detector.pick)"
    )


FOODS = frozenset({
    "apple", "aubergine", "avocado", "bagel", "baguette", "banana", "baumkuchen", "bread",
    "brioche", "brownie", "burrito", "cabbage", "cake", "carrot", "cheese", "cheesecake",
    "chicken", "cookie", "courgette", "croissant", "cucumber", "eggplant", "fish", "ham", "lemon",
    "lime", "mango", "meat", "meatloaf", "melon", "omelette", "onion", "orange", "pancake",
    "pastry", "pepper", "pie", "pineapple", "pizza", "potato", "pumpkin", "quiche", "roast",
    "salmon", "sandwich", "sausage", "squash", "steak", "tart", "terrine", "tofu", "tomato",
    "turkey", "waffle", "watermelon", "zucchini",
})  # fmt: skip
"""Foods a sentence may name an object by: one the scene has no object of is refused."""
SAME_FOOD = {"aubergine": "eggplant", "courgette": "zucchini", "meatloaf": "meat"}
"""Synonyms: the word on the left names the food on the right."""


def _refuse_absent_foods(text: str, targets: list[Target]) -> None:
    """'cut the cucumber' with no cucumber among the objects: say so, rather than that the
    sentence does not say which object (or plan on the banana that is there)."""
    named = {_food(word) for t in targets if t.name for word in t.name.lower().split()}
    if not named:  # nothing says what the objects are: any food may be one of them
        return
    for match in re.finditer(r"[a-z]+", text):
        food = _food(match.group(0))
        if food in FOODS and food not in named:
            raise AddressingError(
                f"the sentence names {match.group(0)!r}, but there is no {food} in the scene "
                f"(the objects: {_listed(targets)}, named by scene.objects): name one of them"
                + ("" if len(targets) == 1 else f", or say 'the {_place_words(targets)[0]} one'")
            )


def _food(word: str) -> str:
    """The food a word names, synonyms as one ('aubergines' -> 'eggplant')."""
    singular = _singular(word)
    return SAME_FOOD.get(singular, singular)


def _listed(targets: list[Target]) -> str:
    """'#1 banana (top), #2 (bottom)'."""
    return ", ".join(f"{t.label} ({_where(t, targets)})" for t in targets)


def _axis(targets: list[Target]) -> int:
    """0 when the objects spread more from left to right than from top to bottom, else 1."""
    spread = [max(t.centre[a] for t in targets) - min(t.centre[a] for t in targets) for a in (0, 1)]
    return 0 if spread[0] >= spread[1] else 1


def _place_words(targets: list[Target]) -> tuple[str, str]:
    return ("left", "right") if _axis(targets) == 0 else ("top", "bottom")


def _where(target: Target, targets: list[Target]) -> str:
    """Its place along the direction the objects spread: left/right, or top/bottom (two
    objects one above the other are the top and the bottom one, not two left ones)."""
    axis = _axis(targets)
    ranked = sorted(targets, key=lambda t: (t.centre[axis], t.centre[1 - axis], t.id))
    rank = ranked.index(target)
    first, last = _place_words(targets)
    if len(targets) == 2:
        return first if rank == 0 else last
    side = "left" if axis == 0 else "top"
    return {0: f"{first}most", len(targets) - 1: f"{last}most"}.get(
        rank, f"{rank + 1}. from the {side}"
    )


def _split(text: str, mentions: list[_Mention]) -> list[str]:
    """One piece of text per mention: cut at the last conjunction between two mentions, the
    mention replaced by 'it'. A piece without design words borrows from its neighbours."""
    bounds = [0]
    for before, after in zip(mentions, mentions[1:], strict=False):
        gap = text[before.end : after.start]
        cuts = list(_CONJUNCTION.finditer(gap))
        bounds.append(before.end + (cuts[-1].start() if cuts else len(gap)))
    bounds.append(len(text))
    pieces = []
    for index, mention in enumerate(mentions):
        start, end = bounds[index], bounds[index + 1]
        piece = text[start : mention.start] + "it" + text[mention.end : end]
        piece = _CONJUNCTION.sub(" ", piece, count=1) if index and _starts_joined(piece) else piece
        pieces.append(" ".join(piece.split()))
    return pieces


def _starts_joined(piece: str) -> bool:
    return re.match(r"\s*(?:[,;]|and\b|then\b|but\b|while\b|plus\b)", piece) is not None


def _mentions(text: str, targets: list[Target]) -> list[_Mention]:
    found: list[_Mention] = []
    for finder in (_by_number, _by_place, _by_size, _others, _by_name, _groups):
        for mention in finder(text, targets):
            if not any(m.start < mention.end and mention.start < m.end for m in found):
                found.append(mention)
    return sorted(found, key=lambda m: m.start)


def _named(noun: str, targets: list[Target]) -> list[Target]:
    """Targets whose declared name is this noun (singular or plural), else every target."""
    stem = _singular(noun)
    named = [t for t in targets if t.name and _singular(t.name.lower()) == stem]
    return named or targets


def _singular(word: str) -> str:
    word = word.strip()
    if word.endswith("ves"):
        return word[:-3] + "f"
    if word.endswith(("oes", "ches", "shes")):
        return word[:-2]
    if word.endswith("s") and not word.endswith("ss"):
        return word[:-1]
    return word


def _by_number(text: str, targets: list[Target]) -> list[_Mention]:
    found = []
    pattern = (
        r"\b(?:object|item|number|no\.?)\s*#?\s*(\d+)\b|#\s*(\d+)\b|\bthe (\d+)th (?:one|1|\w+)\b"
    )
    ids = {t.id for t in targets}
    for match in re.finditer(pattern, text):
        number = int(next(g for g in match.groups() if g is not None))
        if number not in ids:
            raise AddressingError(
                f"{match.group(0)!r}: there is no object {number} "
                f"(the objects are {', '.join(t.label for t in targets)})"
            )
        found.append(_Mention(match.start(), match.end(), match.group(0), (number,)))
    return found


NOT_NOUNS = frozenset(
    {
        "of",
        "and",
        "or",
        "side",
        "sides",
        "edge",
        "edges",
        "half",
        "into",
        "in",
        "with",
        "to",
        "on",
        "at",
        "for",
        "then",
        "but",
        "from",
        "by",
        "as",
        "is",
        "it",
        "its",
        "them",
        "this",
        "that",
    }
)
"""Words after a place word that make it no object phrase ("the left side", "left into")."""

PLACES = {
    "left": (0, min), "leftmost": (0, min), "right": (0, max), "rightmost": (0, max),
    "top": (1, min), "topmost": (1, min), "upper": (1, min), "uppermost": (1, min),
    "bottom": (1, max), "bottommost": (1, max), "lower": (1, max), "lowest": (1, max),
}  # fmt: skip


def _by_place(text: str, targets: list[Target]) -> list[_Mention]:
    words = "|".join(sorted([*PLACES, "middle", "centre", "center"], key=len, reverse=True))
    patterns = [  # "the one on the right" first: its "the right" is not "the right <noun>"
        rf"\bthe\s+(\w+)\s+(?:on|at|to)\s+the\s+({words})\b",
        rf"\b(?:the\s+)?({words})\s+(\w+)\b",
    ]
    found: list[_Mention] = []
    for number, pattern in enumerate(patterns):
        for match in re.finditer(pattern, text):
            place, noun = (match.group(1), match.group(2))
            if number == 0:
                place, noun = noun, place
            if noun in NOT_NOUNS or any(
                m.start < match.end() and match.start() < m.end for m in found
            ):
                continue
            if (
                number == 1
                and not match.group(0).startswith("the")
                and not _is_object_noun(noun, targets)
            ):
                continue
            pool = [] if re.fullmatch(ONE, noun) else _named(noun, targets)
            pool = pool or targets
            found.append(
                _Mention(
                    match.start(),
                    match.end(),
                    match.group(0),
                    (_place(place, pool, match.group(0)),),
                )
            )
    return found


def _is_object_noun(noun: str, targets: list[Target]) -> bool:
    return bool(re.fullmatch(ONE, noun)) or any(
        t.name and _singular(t.name.lower()) == _singular(noun) for t in targets
    )


def _place(place: str, pool: list[Target], phrase: str) -> int:
    if place in ("middle", "centre", "center"):
        if len(pool) < 3:
            raise AddressingError(f"{phrase!r}: there are {len(pool)} objects, none in the middle")
        spread_x = max(t.centre[0] for t in pool) - min(t.centre[0] for t in pool)
        spread_y = max(t.centre[1] for t in pool) - min(t.centre[1] for t in pool)
        axis = 0 if spread_x >= spread_y else 1
        ranked = sorted(pool, key=lambda t: t.centre[axis])
        if len(ranked) % 2 == 0:
            raise AddressingError(f"{phrase!r}: {len(pool)} objects have no single middle one")
        return ranked[len(ranked) // 2].id
    axis, pick = PLACES[place]
    ranked = sorted(pool, key=lambda t: t.centre[axis], reverse=pick is max)
    if len(ranked) >= 2:
        gap = abs(ranked[0].centre[axis] - ranked[1].centre[axis])
        if gap < TIE * min(ranked[0].size[axis], ranked[1].size[axis]):
            raise AddressingError(
                f"{phrase!r} is ambiguous: {ranked[0].label} and {ranked[1].label} are about as "
                f"far {place} (say 'object {ranked[0].id}' or use another word)"
            )
    return ranked[0].id


SIZES = {
    "largest": max, "biggest": max, "larger": max, "bigger": max, "longest": max, "longer": max,
    "smallest": min, "smaller": min, "shortest": min, "shorter": min, "tallest": max,
}  # fmt: skip


def _by_size(text: str, targets: list[Target]) -> list[_Mention]:
    words = "|".join(SIZES)
    found = []
    for match in re.finditer(rf"\bthe\s+({words})(?:\s+(\w+))?\b", text):
        word, noun = match.group(1), match.group(2)
        end = (
            match.end()
            if noun
            and _is_object_noun(noun, targets)
            or noun
            and noun.isalpha()
            and noun not in ("and", "into", "in", "with")
            else match.end(1)
        )
        pool = _named(noun, targets) if noun and not re.fullmatch(ONE, noun) else targets
        long = word.startswith(("long", "short"))

        def measure(t: Target, long: bool = long) -> float:
            return max(t.size) if long else t.area

        ranked = sorted(pool, key=measure, reverse=SIZES[word] is max)
        if len(ranked) >= 2 and abs(measure(ranked[0]) - measure(ranked[1])) < 0.05 * measure(
            ranked[0]
        ):
            raise AddressingError(
                f"{text[match.start() : end]!r} is ambiguous: {ranked[0].label} and "
                f"{ranked[1].label} are about the same size"
            )
        found.append(_Mention(match.start(), end, text[match.start() : end], (ranked[0].id,)))
    return found


def _others(text: str, targets: list[Target]) -> list[_Mention]:
    pattern = rf"\bthe\s+(?:other|remaining)\s+(?:{ONE}s?|\w+)\b|\bthe\s+(?:others|rest)\b"
    return [_Mention(m.start(), m.end(), m.group(0), None) for m in re.finditer(pattern, text)]


def _by_name(text: str, targets: list[Target]) -> list[_Mention]:
    """Objects by their scene.objects name, its last word ('the bread' for a banana bread) or
    a synonym of it ('the aubergine' for an eggplant); longer names first."""
    found: list[_Mention] = []
    for name, named in _aliases(targets):
        stem = re.escape(_singular(name))
        pattern = rf"\b(?:(both|all|each|every|the|2|3|4)\s+(?:of\s+the\s+)?)?({stem}(?:s|es)?|{re.escape(name)})\b"
        for match in re.finditer(pattern, text):
            if any(m.start < match.end() and match.start() < m.end for m in found):
                continue
            plural = (
                match.group(2) != _singular(name)
                and match.group(2) != name
                or match.group(1) in ("both", "all", "each", "every", "2", "3", "4")
            )
            if len(named) > 1 and not plural:
                raise AddressingError(
                    f"{match.group(0)!r} is ambiguous: {len(named)} objects are called {name!r} "
                    f"({', '.join(t.label for t in named)}); say 'the left {name}' or 'both'"
                )
            found.append(
                _Mention(match.start(), match.end(), match.group(0), tuple(t.id for t in named))
            )
    return found


def _aliases(targets: list[Target]) -> list[tuple[str, list[Target]]]:
    """(word or words, the objects it names), longest first: each full name, then each name's
    last word and its synonyms."""
    names: dict[str, list[Target]] = {}
    for target in targets:
        if target.name:
            names.setdefault(target.name.lower(), []).append(target)
    heads: dict[str, list[Target]] = {}
    for name, named in names.items():
        head = name.split()[-1]
        for alias in {head, *(a for a, food in SAME_FOOD.items() if food == _food(head))}:
            if alias not in names:
                heads.setdefault(alias, []).extend(named)
    return sorted([*names.items(), *heads.items()], key=lambda item: -len(item[0]))


def _groups(text: str, targets: list[Target]) -> list[_Mention]:
    everything = tuple(t.id for t in targets)
    patterns = [
        r"\b(?:each|every|both|all)\s+of\s+(?:them|these|those|the\s+(?:\d+\s+)?\w+)\b",
        rf"\b(?:each|every|both|all(?:\s+\d+)?)(?:\s+(?:{ONE}|\w+))?\b",
        r"\b(?:them|these|those|they)\b",
        r"\bthe\s+(?:2|3|4|5|6)\s+(?:of\s+them|\w+)\b",
    ]
    found = []
    for pattern in patterns:
        for match in re.finditer(pattern, text):
            if _GROUP_EXCLUDED.match(text, match.start() + len(match.group(0).split()[0])):
                continue
            if re.search(r"\b(?:for|per)\s+$", text[: match.start()]):
                continue  # "1 slice for each": each guest, not each object
            phrase = match.group(0)
            last = phrase.split()[-1]
            if pattern == patterns[1] and last in ("into", "in", "with", "of", "the", "and", "to"):
                phrase = phrase[: -len(last)].rstrip()
            found.append(_Mention(match.start(), match.start() + len(phrase), phrase, everything))
    return found
