"""A design intent laid out exactly on the object in a crop: keypoint pairs in crop pixels.

Shared by the offline planner and by named-design answers of any backend: the object is
measured in the crop (keymps.designs.crop_shape), the design laid out in millimetres
(keymps.designs.layout), then converted to crop pixels and kept inside the crop (cuts: inside
the object's bounding box, as the paper's lines are).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from keymps.designs.grammar import Intent
from keymps.errors import KeympsError


def clip_to_box(pairs_px: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Shorten each segment along its own direction so both ends stay inside [low, high]."""
    shifted = clip_to_image(pairs_px - low, *(high - low))
    return shifted + low


def clip_to_image(pairs_px: np.ndarray, width: float, height: float) -> np.ndarray:
    """Shorten each segment along its own direction so both ends stay in [0, width] x [0, height]."""
    clipped = []
    limit = np.array([float(width), float(height)])
    for start, end in pairs_px:
        a, b = start.copy(), end.copy()
        for point, other in ((a, b), (b, a)):
            direction = other - point
            if np.all(point >= 0) and np.all(point <= limit):
                continue
            t_needed = 0.0
            for axis in range(2):
                if point[axis] < 0 and direction[axis] > 0:
                    t_needed = max(t_needed, -point[axis] / direction[axis])
                elif point[axis] > limit[axis] and direction[axis] < 0:
                    t_needed = max(t_needed, (limit[axis] - point[axis]) / direction[axis])
            point += min(t_needed, 1.0) * direction
        clipped.append([np.clip(a, 0, limit), np.clip(b, 0, limit)])
    return np.array(clipped, dtype=float).reshape(-1, 2, 2)


def place_design(
    intent: Intent,
    crop: np.ndarray,
    mask: np.ndarray | None,
    metres_per_px: tuple[float, float],
    max_pairs: int,
    line_width_mm: float = 0.0,
) -> tuple[np.ndarray, str]:
    """((K, 2, 2) pairs in crop pixels, a one-sentence rationale) for `intent` on this crop.

    With the icing line's width, an icing design whose lines would merge is refused."""
    from keymps.designs.crop_shape import measure
    from keymps.designs.layout import design

    mm_per_px = (1000.0 * metres_per_px[0], 1000.0 * metres_per_px[1])
    shape = measure(crop, mask, mm_per_px)
    try:
        pairs_mm, layout = design(intent, shape, max_pairs)
    except ValueError as error:  # a design that cannot exist on this object
        raise KeympsError(
            f"cannot lay out {intent.describe()} on the {shape.describe()}: {error}"
        ) from None
    if intent.family == "icing" and line_width_mm > 0:
        refuse_merging(pairs_mm, line_width_mm, intent.describe(), shape)
    height, width = crop.shape[:2]
    pairs_px = clip_to_image(shape.to_pixels(pairs_mm), width - 1, height - 1)
    if intent.family == "cut":
        # cuts reach the object's edges, not beyond its bounding box (the paper's lines)
        outline_px = shape.to_pixels(shape.outline.polygon)
        pairs_px = clip_to_box(pairs_px, outline_px.min(axis=0), outline_px.max(axis=0))
    if len(pairs_px) > max_pairs:
        raise KeympsError(
            f"the design {intent.describe()} needs {len(pairs_px)} keypoint pairs, more than "
            f"planner.max_pairs = {max_pairs}"
        )
    if len(pairs_px) == 0:
        raise KeympsError(f"found no place for {intent.describe()} on the {shape.describe()}")
    return pairs_px, layout


def smallest_scale(pairs_mm: np.ndarray, line_width_mm: float, centre: np.ndarray) -> float:
    """How many times larger (about `centre`) a drawing must be for its strokes not to merge."""
    from keymps.designs.legibility import merging_strokes

    low, high = 1.0, 2.0
    while merging_strokes(centre + high * (pairs_mm - centre), line_width_mm) and high < 64:
        low, high = high, 2 * high
    for _ in range(12):
        middle = (low + high) / 2
        if merging_strokes(centre + middle * (pairs_mm - centre), line_width_mm):
            low = middle
        else:
            high = middle
    return high


def refuse_merging(pairs_mm: np.ndarray, line_width_mm: float, what: str, shape: Any) -> None:
    """Refuse a design whose icing lines would run into each other, saying what size works."""
    from keymps.designs.legibility import merging_strokes

    merge = merging_strokes(pairs_mm, line_width_mm)
    if merge is None:
        return
    gap, _ = merge
    o = shape.outline
    factor = smallest_scale(pairs_mm, line_width_mm, np.asarray(o.centre, float))
    if o.kind == "round":
        needed = f"{2 * o.radius * factor / 10:.1f} cm across"
    else:
        needed = f"{o.length * factor / 10:.1f} x {o.width * factor / 10:.1f} cm"
    raise KeympsError(
        f"refuses {what} on the {shape.describe()}: its lines would come {gap:.1f} mm apart "
        f"and merge with a {line_width_mm:g} mm icing line (robot.tool.line_width); it needs "
        f"an object at least {needed} ({factor:.2f} times larger), a thinner line, or a "
        "simpler design"
    )
