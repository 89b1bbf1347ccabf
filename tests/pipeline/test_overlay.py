"""plan.png: what the overlay draws, and where."""

from __future__ import annotations

import numpy as np

from keymps.pipeline.overlay import draw_plan
from keymps.types import Detection, Plan

GRAY = 90


def scene() -> tuple[np.ndarray, Detection]:
    image = np.full((240, 320, 3), GRAY, np.uint8)
    detection = Detection(
        bbox_px=(60, 40, 260, 200),
        crop=image[30:210, 50:270],
        crop_origin_px=(50, 30),
        others_px=((5, 5, 30, 30),),
    )
    return image, detection


def plan(pairs_px: list) -> Plan:
    pairs = np.asarray(pairs_px, dtype=float)
    return Plan("line", pairs - (50, 30), pairs, "test")


def is_red(pixel: np.ndarray) -> bool:
    b, g, r = (int(v) for v in pixel)
    return r > 180 and g < 80 and b < 80


def is_green(pixel: np.ndarray) -> bool:
    b, g, r = (int(v) for v in pixel)
    return g > 150 and r < 80 and b < 80


def test_lines_dots_numbers_and_boxes_are_drawn_where_the_pairs_are() -> None:
    image, detection = scene()
    pairs = [[[80, 120], [240, 120]], [[160, 60], [160, 180]], [[100.5, 170.5], [100.5, 170.5]]]
    before = image.copy()
    drawn = draw_plan(image, detection, plan(pairs))
    np.testing.assert_array_equal(image, before)  # the input is not modified
    assert drawn.shape == image.shape and drawn.dtype == np.uint8

    # Red along each line (pixel (x, y) is at row y, column x; keypoints sit at pixel centres).
    for x in range(95, 226, 10):
        assert is_red(drawn[119, x]) or is_red(drawn[120, x]), x
    for y in range(75, 166, 10):
        assert is_red(drawn[y, 159]) or is_red(drawn[y, 160]), y
    # The dot pair: a small red circle around (100, 170), its centre left unpainted.
    ring = [drawn[170, 100 + dx] for dx in range(-6, 7)]
    assert any(is_red(p) for p in ring)
    assert not is_red(drawn[170, 100])
    # Green order numbers, three of them: green pixels exist near each start point.
    for start in ([80, 120], [160, 60], [100, 170]):
        x, y = start
        window = drawn[max(0, y - 30) : y + 30, max(0, x - 30) : x + 30].reshape(-1, 3)
        assert any(is_green(p) for p in window), start
    # The detection box (cyan-ish) and the other region (gray) are outlined.
    assert tuple(drawn[40, 150]) == (255, 200, 0)
    assert tuple(drawn[199, 150]) == (255, 200, 0)
    assert tuple(drawn[5, 15]) == (160, 160, 160)
    # Far from everything the image is unchanged.
    assert tuple(drawn[230, 310]) == (GRAY, GRAY, GRAY)


def test_grayscale_input_and_scale() -> None:
    image, detection = scene()
    gray = image[:, :, 0]
    drawn = draw_plan(gray, detection, plan([[[80, 120], [240, 120]]]), scale=2.0)
    assert drawn.shape == (480, 640, 3)
    assert is_red(drawn[240, 320]) or is_red(drawn[241, 320])
