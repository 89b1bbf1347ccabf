"""Generated length phrasings for the offline planner (issue 39 item 1), with what each means.

`width_cases()` writes slice widths in every form people use (digits, words, "half", "a
quarter", "1/2", "0.5", ".5", "½", "one and a half", "an inch and a half"), every unit (mm,
millimetres, cm, centimetres, inch, inches, in, ") with and without hyphens, at different places
of the sentence and with different nouns (slices, rounds, coins, pieces, chunks, strips, sticks);
`edge_cases()` writes distances from a cake's edge the same ways. `judge_*` plan each sentence
on a synthetic object of known size with the real offline planner and compare the plan's
geometry, in millimetres, with what the sentence says: `read` (it matches), `refused` (one clean
error) or `misread` (a plan whose geometry differs: a confident wrong motion).

Run it to print the tally: `python tests/helpers/phrasings.py` (with PYTHONPATH=<checkout>
first on the path, on any checkout: it uses only read_instruction and make_plan).
"""

from __future__ import annotations

import functools
import itertools
import math
import re
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from synthetic_crops import CUTTING, ICING, MM_PER_PX, Scene, make_scene, plan_for  # noqa: E402

INCH = 25.4
UNIT_WORDS = {
    "mm": ["mm", "millimetres", "millimeter"],
    "cm": ["cm", "centimetres", "centimeter"],
    "inch": ["inch", "inches", "in", '"'],
}
MM_PER_UNIT = {"mm": 1.0, "cm": 10.0, "inch": INCH}
NUMBER_FORMS: dict[float, list[str]] = {
    0.25: ["1/4", "0.25", "quarter", "a quarter", "a quarter of {a}", "¼"],
    0.5: ["1/2", "0.5", ".5", "half", "a half", "half {a}", "½", "one half"],
    0.75: ["3/4", "0.75", "three quarters of {a}", "three-quarter", "¾"],
    1.0: ["1", "one", "{a}"],
    1.5: ["1 1/2", "1.5", "one and a half", "1 and a half", "{a} {u} and a half", "1½", "1-1/2"],
    2.0: ["2", "two"],
    2.5: ["2.5", "two and a half", "2 1/2"],
    3.0: ["3", "three"],
    5.0: ["5", "five"],
    10.0: ["10", "ten"],
    15.0: ["15", "fifteen"],
    20.0: ["20", "twenty"],
}
VALUES = {"mm": [5.0, 10.0, 15.0, 20.0], "cm": [0.5, 1.0, 1.5, 2.0, 2.5, 3.0],
          "inch": [0.25, 0.5, 0.75, 1.0, 1.5]}  # fmt: skip
SYMBOLS = ('"', "in")
"""Units written only after digits ('1/2"', '0.5 in'): "half an in" is no English."""
NOUNS = ["slices", "rounds", "coins", "pieces", "chunks", "strips", "sticks"]
WIDTH_TEMPLATES = [
    "Cut it into {q} {noun}",
    "Slice it into {noun} {q} thick",
    "Cut {q} thick {noun}",
    "Cut the cucumber into {q} {noun}, please",
    "{q} {noun}",
    "Cut it into {noun} of {q}",
    "I'd like {noun} about {q} thick",
    "Cut {count} {q} {noun}",
]


@dataclass(frozen=True)
class Phrase:
    sentence: str
    mm: float
    """The length the sentence gives, millimetres."""
    noun: str = ""
    count: int | None = None
    written: str = ""
    """How the number was written (for the tally by form)."""
    unit: str = ""


def _quantity(form: str, unit: str, word: str, hyphen: bool) -> str | None:
    """'half an inch', '1/2-inch', '0.5"' ... or None when the form does not fit the unit."""
    article = "an" if word.startswith(("inch", "in")) else "a"
    if word in SYMBOLS and re.search(r"[a-z{]", form):
        return None
    if "{a}" in form:
        if word in SYMBOLS or word.endswith(("es", "s")) and "{u}" not in form:
            return None
        text = form.replace("{a}", article).replace("{u}", word)
        return text if "{u}" in form else f"{text} {word}"
    joint = "-" if hyphen and word not in SYMBOLS else ("" if word == '"' else " ")
    return f"{form}{joint}{word}"


def width_cases(per_quantity: int = 3) -> list[Phrase]:
    """Every number form x unit word x hyphen, each in `per_quantity` of the templates x nouns
    (taken in turn, so that every template meets every noun and form across the set)."""
    shapes = list(itertools.product(WIDTH_TEMPLATES, NOUNS))
    cases, turn = [], 0
    for unit, words in UNIT_WORDS.items():
        for value in VALUES[unit]:
            for form, word, hyphen in itertools.product(NUMBER_FORMS[value], words, (False, True)):
                q = _quantity(form, unit, word, hyphen)
                if q is None:
                    continue
                for _ in range(per_quantity):
                    template, noun = shapes[turn % len(shapes)]
                    turn += 7  # coprime with len(shapes): every pair comes round
                    count = 3 if "{count}" in template else None
                    sentence = template.format(q=q, noun=noun, count=count)
                    cases.append(
                        Phrase(sentence, value * MM_PER_UNIT[unit], noun, count, form, word)
                    )
    return list({c.sentence: c for c in cases}.values())


EDGE_TEMPLATES = [
    "Put 12 dots around the cake {q} from the edge",
    "pipe dots around the cake, {q} in from the rim",
    "Pipe a ring of icing {q} from the edge",
    "put 10 rosettes around the cake with a {q} margin",
]


def edge_cases() -> list[Phrase]:
    cases = []
    for unit, words in UNIT_WORDS.items():
        for value in VALUES[unit]:
            mm = value * MM_PER_UNIT[unit]
            if not 5.0 <= mm <= 40.0:
                continue
            for form, word, template in itertools.product(
                NUMBER_FORMS[value], words, EDGE_TEMPLATES
            ):
                q = _quantity(form, unit, word, "margin" in template and word not in SYMBOLS)
                if q is not None:
                    cases.append(Phrase(template.format(q=q), mm, written=form, unit=word))
    return list({c.sentence: c for c in cases}.values())


# --- judging a plan ---------------------------------------------------------------------------

LOG_SIZE_MM = (200.0, 40.0)
"""The long object the widths are cut on: a 20 x 4 cm block, aligned with the image."""
CAKE_MM = 150.0
SCENES = {"log": lambda: make_scene("rect", LOG_SIZE_MM), "cake": lambda: make_scene("disk", (CAKE_MM, CAKE_MM))}  # fmt: skip
_PLANS: dict[tuple[str, str], tuple[np.ndarray | None, str]] = {}


def planned(sentence: str, scene_name: str) -> tuple[np.ndarray | None, str]:
    """(pairs in scene pixels, '') or (None, the refusal) of the offline planner. Plans are
    kept by the grammar's reading: sentences read alike are laid out alike (the layout sees the
    intent and the crop only), so each reading is planned once."""
    from keymps.designs.grammar import read_instruction
    from keymps.errors import KeympsError

    try:
        reading = read_instruction(sentence).describe()
    except KeympsError as error:
        return None, str(error)
    key = (reading, scene_name)
    if key not in _PLANS:
        primitives = ICING if scene_name == "cake" else CUTTING
        try:
            plan, _ = plan_for(sentence, _scene(scene_name), primitives)
            _PLANS[key] = np.asarray(plan.pairs_px, float), ""
        except KeympsError as error:
            _PLANS[key] = None, str(error)
    return _PLANS[key]


_SCENES: dict[str, Scene] = {}


def _scene(name: str) -> Scene:
    if name not in _SCENES:
        _SCENES[name] = SCENES[name]()
    return _SCENES[name]


@functools.cache
def object_extent_mm(scene_name: str, axis: int) -> tuple[float, float]:
    """(low, high) of the drawn object along an image axis, millimetres (pixel edges)."""
    from synthetic_crops import BOARD_BGR

    image = _scene(scene_name).scene.image
    on = np.abs(image.astype(int) - np.array(BOARD_BGR)).max(axis=2) > 30
    index = np.flatnonzero(on.any(axis=axis))
    return index[0] * MM_PER_PX, (index[-1] + 1) * MM_PER_PX


def expected_offsets(length: float, width: float, count: int | None) -> np.ndarray:
    """Where slices of `width` fall from the object's end: `count` of them, or as many as
    leave an end piece of at least half a slice (the eval's ground-truth rule)."""
    n = count if count is not None else int(math.floor(length / width + 0.02))
    offsets = np.arange(1, n + 1) * width
    offsets = offsets[offsets < length - 0.02 * width]
    return offsets if count is not None else offsets[offsets <= length - width / 2 + 1e-9]


def judge_width(phrase: Phrase) -> tuple[str, str]:
    """('read' | 'refused' | 'misread', detail) for one width sentence on the 20 x 4 cm block:
    the cuts must fall every `phrase.mm` from one end (across it; along it for strips)."""
    pairs, refusal = planned(phrase.sentence, "log")
    if pairs is None:
        return "refused", refusal
    if phrase.noun == "sticks":
        return "misread", "sticks need cuts both ways; no design has them"
    along = 1 if phrase.noun == "strips" else 0  # strips run along the object's length
    ends = pairs[:, :, along]
    if np.abs(ends[:, 0] - ends[:, 1]).max() * MM_PER_PX > 0.5:
        return "misread", f"cuts are not across image axis {along}"
    low, high = object_extent_mm("log", along)
    positions = np.sort(ends.mean(axis=1) * MM_PER_PX - low)
    want = expected_offsets(high - low, phrase.mm, phrase.count)
    if len(positions) != len(want) or np.abs(positions - want).max(initial=0) > 1.0:
        return "misread", f"cuts at {np.round(positions, 1).tolist()} mm, not {want.round(1)}"
    return "read", ""


def judge_edge(phrase: Phrase) -> tuple[str, str]:
    """How far in from the edge of a 15 cm cake the plan's ring (dots or line) runs."""
    pairs, refusal = planned(phrase.sentence, "cake")
    if pairs is None:
        return "refused", refusal
    scene = _scene("cake")
    points = pairs.reshape(-1, 2) * MM_PER_PX
    radii = np.linalg.norm(points - np.asarray(scene.centre_px) * MM_PER_PX, axis=1)
    low, high = object_extent_mm("cake", 0)
    inset = (high - low) / 2 - radii.max()
    if abs(inset - phrase.mm) > 1.0:
        return "misread", f"ring {inset:.1f} mm in from the edge, not {phrase.mm:.1f}"
    return "read", ""


def tally(cases: list[Phrase], judge) -> tuple[Counter[str], list[tuple[Phrase, str]]]:  # type: ignore[no-untyped-def]
    outcomes: Counter[str] = Counter()
    misread = []
    for phrase in cases:
        outcome, detail = judge(phrase)
        outcomes[outcome] += 1
        if outcome == "misread":
            misread.append((phrase, detail))
    return outcomes, misread


if __name__ == "__main__":
    import warnings

    warnings.simplefilter("ignore")
    for name, cases, judge in (
        ("widths", width_cases(), judge_width),
        ("edge distances", edge_cases(), judge_edge),
    ):
        outcomes, misread = tally(cases, judge)
        print(
            f"{name}: {len(cases)} sentences: " + ", ".join(f"{k} {v}" for k, v in outcomes.items())
        )
        for phrase, detail in misread[:8]:
            print(f"  misread: {phrase.sentence!r}: {detail}")
