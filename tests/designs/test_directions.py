"""Directions are the object's own (issue 39 item 2): "vertically" on a turned cake or eggplant.

"Cut it vertically into 3 slices" on a square cake turned 10 degrees cut image-vertical lines
(pieces 44.2, 57.1, 44.8 cm²) while "8 equal slices" followed the turn, and "a single
horizontal slice in the middle" of an eggplant turned 20 degrees cut a diagonal. Now vertical and
horizontal mean the object's axis nearest the image's vertical or horizontal. Generated objects
turned -40..40 degrees are planned by the offline planner and the pieces its cuts leave are
measured with keymps.eval.parts (Appendix F's test: equal within 5 %).
"""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from helpers.synthetic_crops import MM_PER_PX, make_scene, plan_for

from keymps.errors import KeympsError
from keymps.eval.parts import check_equal_parts

TOLERANCE = 0.05
"""Appendix F: each piece within 5 % of an equal share."""


def _outline_mm(shape: str, sizes: tuple[float, float], angle: float, centre) -> np.ndarray:
    """The drawn object's outline in millimetres (the geometry make_scene drew)."""
    import cv2

    c = (centre[0], centre[1])
    size = (sizes[0] / MM_PER_PX, sizes[1] / MM_PER_PX)
    if shape == "rect":
        points = cv2.boxPoints((c, size, angle))
    else:
        t = np.linspace(0, 2 * math.pi, 720, endpoint=False)
        a, r = math.radians(angle), np.array(size) / 2
        local = np.stack([r[0] * np.cos(t), r[1] * np.sin(t)], axis=1)
        points = local @ np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]]) + c
    return np.asarray(points, float) * MM_PER_PX


def _axis_nearest(angle_deg: float, image_deg: float) -> float:
    """The object's axis (its length direction at angle_deg, or across) nearest image_deg."""
    turn = math.remainder(angle_deg - image_deg, 90.0)
    return image_deg + turn


def _cut_angles(pairs: np.ndarray) -> np.ndarray:
    d = pairs[:, 1] - pairs[:, 0]
    return np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 180.0


def _angle_gap(a: np.ndarray, b: float) -> np.ndarray:
    return np.abs((a - b + 90.0) % 180.0 - 90.0)


def _planned(sentence: str, shape: str, sizes: tuple[float, float], angle: float):
    scene = make_scene(shape, sizes, angle_deg=angle)
    plan, _ = plan_for(sentence, scene, name="cake" if shape == "rect" else "eggplant")
    cuts = np.asarray(plan.pairs_px, float) * MM_PER_PX
    return plan, cuts, _outline_mm(shape, sizes, angle, scene.centre_px)


def _cases(count: int, seed: int) -> list[tuple[float, float, float, int]]:
    rng = random.Random(seed)
    return [
        (rng.uniform(-40.0, 40.0), rng.uniform(120, 190), rng.uniform(0.9, 1.0), rng.randint(2, 5))
        for _ in range(count)
    ]


@pytest.mark.parametrize("direction", ["vertically", "horizontally"])
def test_turned_square_cakes_are_cut_along_their_own_sides_into_equal_pieces(
    direction: str,
) -> None:
    """60 square cakes turned -40..40 degrees, 2 to 5 parts: every piece within 5 %."""
    failures = []
    for angle, side, ratio, parts in _cases(60, seed=len(direction)):
        sizes = (side, side * ratio)
        plan, cuts, outline = _planned(
            f"Cut it {direction} into {parts} slices", "rect", sizes, angle
        )
        check = check_equal_parts(outline / 1000, cuts / 1000, parts, TOLERANCE)
        along = _axis_nearest(angle, 90.0 if direction == "vertically" else 0.0)
        off_axis = _angle_gap(_cut_angles(cuts), along).max()
        if not check.ok or off_axis > 0.7:
            failures.append((round(angle, 1), parts, check.describe(), round(off_axis, 2)))
    assert failures == [], failures


def test_the_issues_square_cake_turned_10_degrees() -> None:
    plan, cuts, outline = _planned("Cut it vertically into 3 slices", "rect", (150, 150), 10.0)
    check = check_equal_parts(outline / 1000, cuts / 1000, 3, TOLERANCE)
    assert check.ok, check.describe()  # before issue 39: 44.2, 57.1, 44.8 cm²
    assert "along the object's own axes (turned 10 degrees" in plan.rationale


@pytest.mark.parametrize("seed", range(40))
def test_a_turned_eggplant_gets_its_middle_slice_along_its_length(seed: int) -> None:
    """An ellipse 3 to 4 times as long as wide, turned -40..40 degrees: 'a single horizontal
    slice in the middle' runs along its long axis and leaves two equal halves; 'vertically into
    N' cuts across it at equal steps of its length."""
    rng = random.Random(seed)
    angle = rng.uniform(-40.0, 40.0)
    length = rng.uniform(150, 220)
    sizes = (length, length / rng.uniform(3.0, 4.0))
    _, cuts, outline = _planned("A single horizontal slice in the middle", "ellipse", sizes, angle)
    assert len(cuts) == 1 and _angle_gap(_cut_angles(cuts), angle).max() < 1.0, angle
    halves = check_equal_parts(outline / 1000, cuts / 1000, 2, TOLERANCE)
    assert halves.ok, (angle, halves.describe())  # the issue's diagonal left unequal halves

    parts = rng.randint(2, 6)
    _, cuts, outline = _planned(f"Cut it vertically into {parts} slices", "ellipse", sizes, angle)
    assert _angle_gap(_cut_angles(cuts), angle + 90.0).max() < 1.0, angle
    axis = np.array([math.cos(math.radians(angle)), math.sin(math.radians(angle))])
    along = np.sort(cuts.mean(axis=1) @ axis)
    ends = outline @ axis
    want = ends.min() + np.arange(1, parts) * (ends.max() - ends.min()) / parts
    assert np.abs(along - want).max() < 1.0, (angle, along, want)


def test_an_object_turned_45_degrees_has_no_vertical() -> None:
    for shape, sizes in (("rect", (150.0, 150.0)), ("ellipse", (200.0, 60.0))):
        with pytest.raises(KeympsError, match="turned 45 degrees from the image's axes"):
            _planned("Cut it vertically into 3 slices", shape, sizes, 45.0)


@pytest.mark.parametrize(
    ("sentence", "refusal"),
    [
        ("Cut it into 3 strips", "a round object has no strips"),
        ("cut it into 2 cm strips", "a round object has no strips"),
        ("cut it lengthwise into 4 pieces", "a round object has no length"),
        ("Slice it into half-inch rounds", "rounds are slices across a long object"),
    ],
)
def test_a_round_pizza_has_no_strips_and_no_length(sentence: str, refusal: str) -> None:
    scene = make_scene("disk", (150, 150))
    with pytest.raises(KeympsError, match=refusal):
        plan_for(sentence, scene)


def test_strips_of_a_long_object_run_along_it() -> None:
    plan, cuts, outline = _planned("Cut it into 3 strips", "rect", (200.0, 60.0), 15.0)
    assert len(cuts) == 2 and _angle_gap(_cut_angles(cuts), 15.0).max() < 0.7
    assert check_equal_parts(outline / 1000, cuts / 1000, 3, TOLERANCE).ok


def test_a_round_cakes_axes_are_the_images() -> None:
    """Table I case 10 (a cabbage, 'into 3 parts horizontally'): image-horizontal cuts."""
    scene = make_scene("disk", (150, 150))
    plan, _ = plan_for("Slice the object into 3 parts horizontally", scene, name="cabbage")
    cuts = np.asarray(plan.pairs_px, float)
    assert len(cuts) == 2 and _angle_gap(_cut_angles(cuts), 0.0).max() < 1e-6
    assert "own axes" not in plan.rationale
