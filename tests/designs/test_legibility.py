"""Icing designs too small for the nozzle's line: strokes that would merge are refused, with
the smallest object size that works (issue 19 item 9)."""

from __future__ import annotations

import random
import re

import numpy as np
import pytest
from helpers.synthetic_crops import ICING, make_scene, plan_for

from keymps.designs import patterns
from keymps.designs.legibility import merging_strokes
from keymps.errors import KeympsError


def _gap_between_characters(text: str, height: float) -> float:
    """The closest two characters of a seven-segment text come, from dense samples."""
    drawn = [patterns.seven_segment(ch, (0, 0), height) for ch in text]
    width, _ = patterns.seven_segment_size("0", height)
    step = width + patterns.DIGIT_GAP * height
    fractions = np.linspace(0, 1, 101)[:, None]
    points = [
        np.concatenate([p[0] + fractions * (p[1] - p[0]) for p in pairs]) + [k * step, 0]
        for k, pairs in enumerate(drawn)
    ]
    return min(
        float(np.linalg.norm(a[:, None] - b[None], axis=2).min())
        for i, a in enumerate(points)
        for b in points[i + 1 :]
    )


@pytest.mark.parametrize("seed", range(40))
def test_seven_segment_text_merges_exactly_when_its_lines_come_closer_than_the_line_width(
    seed: int,
) -> None:
    rng = random.Random(seed)
    text = "".join(rng.choice("0123456789") for _ in range(rng.randint(2, 5)))
    width = rng.uniform(1.0, 6.0)
    height = rng.uniform(5.0, 40.0)
    merge = merging_strokes(patterns.seven_segment(text, (0, 0), height), width)
    # within a character parallel segments are half a height apart (b-f, a-g, g-d)
    parallel = 0.5 * height if any(ch in "0234568 9" for ch in text) else np.inf
    gap = min(_gap_between_characters(text, height), parallel)
    if abs(gap - width) > 0.05 * width:
        assert (merge is not None) == (gap < width), (text, width, height, gap, merge)
    if merge is not None:
        assert merge[0] == pytest.approx(min(gap, merge[0]), abs=0.02 * height)
    # a drawing and its line scaled together merge alike
    scaled = merging_strokes(patterns.seven_segment(text, (0, 0), 3 * height), 3 * width)
    assert (scaled is None) == (merge is None)


def test_crossing_lines_corners_and_star_tips_do_not_count_as_merging() -> None:
    assert merging_strokes(patterns.star((0, 0), 40, 5), 4.0) is None
    square = np.array(
        [[[0, 0], [30, 0]], [[30, 0], [30, 30]], [[30, 30], [0, 30]], [[0, 30], [0, 0]]]
    )
    assert merging_strokes(square, 4.0) is None
    cross = np.array([[[0, 0], [30, 30]], [[0, 30], [30, 0]]])
    assert merging_strokes(cross, 4.0) is None
    two_dots = np.array([[[0, 0], [0, 0]], [[3, 0], [3, 0]]])
    assert merging_strokes(two_dots, 4.0) == (3.0, pytest.approx(np.array([1.5, 0])))


def test_2026_on_a_4_5_cm_cake_is_refused_with_the_size_that_works() -> None:
    scene = make_scene("disk", (45, 45))  # measured 4.6 cm across
    with pytest.raises(KeympsError) as refused:
        plan_for("Write 2026 on the cake", scene, ICING, robot={"tool": "piping_bag"})
    message = str(refused.value)
    assert "lines would come 3.6 mm apart and merge with a 4 mm icing line" in message
    needed = float(re.search(r"at least (\d+\.\d) cm across", message).group(1))
    plan, _ = plan_for(
        "Write 2026 on the cake",
        make_scene("disk", (10 * needed + 1, 10 * needed + 1)),
        ICING,
        robot={"tool": "piping_bag"},
    )
    assert plan.num_pairs > 0  # the size it names works
    # a finer nozzle draws it on the small cake
    thin = {"tool": {"name": "piping_bag", "line_width": 0.002}}
    assert plan_for("Write 2026 on the cake", scene, ICING, robot=thin)[0].num_pairs > 0


@pytest.mark.parametrize("seed", range(12))
def test_any_icing_design_is_drawn_legibly_or_refused_with_a_size_that_works(seed: int) -> None:
    rng = random.Random(seed)
    sentence = rng.choice(
        [
            "Write 2026 on the cake",
            "Write 12 on the cake",
            "Draw a spiral",
            "Make 3 layers of icing around the cake",
            "Put 20 icing dots around the cake",
            "Put dots around and a spiral in the middle",
        ]
    )
    size = rng.uniform(30.0, 140.0)
    width = rng.uniform(0.002, 0.006)
    robot = {"tool": {"name": "piping_bag", "line_width": width}}
    try:
        plan, _ = plan_for(sentence, make_scene("disk", (size, size)), ICING, robot=robot)
    except KeympsError as error:
        found = re.search(r"at least (\d+\.\d) cm across", str(error))
        assert found, str(error)
        bigger = 10 * float(found.group(1)) * 1.05
        plan, _ = plan_for(sentence, make_scene("disk", (bigger, bigger)), ICING, robot=robot)
    assert plan.num_pairs > 0
