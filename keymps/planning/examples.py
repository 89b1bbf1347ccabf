"""The prompts' worked examples, written in the task's coordinate convention.

Examples are data in pixels of a described example image; `examples_text` writes every point
as the model must write it (pixels [x, y], or [x, y] / [y, x] normalized to 0-1000), and adds
named-design examples when `planner.answer` allows designs.
"""

from __future__ import annotations

from dataclasses import dataclass

from keymps.planning.coordinates import Convention, point_text

Pixels = tuple[tuple[tuple[float, float], tuple[float, float]], ...]


@dataclass(frozen=True)
class Example:
    """One worked example in a prompt: a sentence, what it asks for, the pairs that answer it."""

    sentence: str
    what: str
    pairs: Pixels


@dataclass(frozen=True)
class ExampleImage:
    """An example object image of a prompt and the sentences answered on it."""

    size: tuple[int, int]
    describe: str
    """The object in this image; {0}, {1} ... are `points`, written in the convention."""
    points: tuple[tuple[float, float], ...]
    examples: tuple[Example, ...]


def _v(x: float) -> tuple[tuple[float, float], tuple[float, float]]:
    return ((x, 35), (x, 165))


CUTTING: tuple[ExampleImage, ...] = (
    ExampleImage(
        (400, 200),
        "an object whose bounding box runs from {0} to {1}",
        ((20, 40), (380, 160)),
        (
            Example("Cut it vertically into 4 equal slices",
                    "three vertical cuts at a quarter, half and three quarters of its width",
                    (_v(110), _v(200), _v(290))),
            Example("Slice both tips", "one cut near each end", (_v(50), _v(350))),
            Example("A single horizontal slice in the middle",
                    "one cut from left to right through the middle", (((15, 100), (385, 100)),)),
            Example("With 1 pixel = 0.5 mm: cut it into 5 cm slices",
                    "cuts 5 cm (100 pixels) apart, from the object's left end",
                    (_v(120), _v(220), _v(320))),
        ),
    ),
    ExampleImage(
        (300, 300),
        "a round cake centred at {0}, 240 pixels across",
        ((150, 150),),
        (
            Example("Cut it into 4 equal parts", "two cuts through the centre",
                    (((150, 25), (150, 275)), ((25, 150), (275, 150)))),
        ),
    ),
)  # fmt: skip

ICING: tuple[ExampleImage, ...] = (
    ExampleImage(
        (400, 400),
        "a round cake centred at {0}, 320 pixels across",
        ((200, 200),),
        (
            Example("4 dots around the cake, away from the edge", "four dots (start = end)",
                    (((200, 75), (200, 75)), ((325, 200), (325, 200)),
                     ((200, 325), (200, 325)), ((75, 200), (75, 200)))),
            Example("A line across the middle", "one stroke", (((80, 200), (320, 200)),)),
            Example("A dot on the middle of each of the 4 slices (first cut vertical)",
                    "one dot at the middle of each quarter",
                    (((268, 132), (268, 132)), ((268, 268), (268, 268)),
                     ((132, 268), (132, 268)), ((132, 132), (132, 132)))),
            Example("The digit 1 in the middle", "two vertical segments",
                    (((210, 150), (210, 200)), ((210, 200), (210, 250)))),
        ),
    ),
)  # fmt: skip

DESIGN_EXAMPLES = {
    "cutting": (
        ("Cut the cake into six equal parts", '{"name": "equal", "count": 6}'),
        ("The loaf is 30 cm long, cut it vertically into 5 cm slices",
         '{"name": "width", "slice_width_cm": 5, "object_length_cm": 30, '
         '"orientation": "vertical"}'),
    ),
    "icing": (
        ("Put 9 dots around the cake", '{"name": "dots_ring", "count": 9}'),
        ("Write 27 on the cake", '{"name": "digits", "text": "27"}'),
    ),
}  # fmt: skip
"""(sentence, design) examples; parameters not shown are null."""


def _pairs_text(pairs: Pixels, convention: Convention, size: tuple[int, int]) -> str:
    written = (
        f"[{point_text(*start, convention, size)}, {point_text(*end, convention, size)}]"
        for start, end in pairs
    )
    return "[" + ", ".join(written) + "]"


def examples_text(family: str, convention: Convention, answer: str) -> str:
    """The Examples section's body for a family, in the convention, for the answer form."""
    lines: list[str] = []
    if answer != "design":
        for image in CUTTING if family == "cutting" else ICING:
            size = image.size
            where = image.describe.format(*(point_text(*p, convention, size) for p in image.points))
            lines.append(f"For {where} in a {size[0]} x {size[1]} image:")
            for example in image.examples:
                lines.append(
                    f'- "{example.sentence}" -> {example.what}: '
                    f"{_pairs_text(example.pairs, convention, size)}"
                )
            lines.append("")
    if answer != "pairs":
        lines.append("Named designs (keymps lays them out exactly on the object):")
        for sentence, design in DESIGN_EXAMPLES[family]:
            lines.append(f'- "{sentence}" -> "design": {design}')
    return "\n".join(lines).strip()
