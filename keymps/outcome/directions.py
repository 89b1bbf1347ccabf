"""Directions on the board: the object's measured frame (its kind and own axes), the direction
of a cut's line, and the angle between two lines. Board frame, radians; the verdict's checks
and the pieces' shapes hold cuts against them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from keymps.types import CutEffect


@dataclass(frozen=True)
class Shape:
    """An object's measured frame: its kind and its own axes (board frame, radians)."""

    kind: str
    """round, square or elongated (keymps.designs.crop_shape.classify)."""
    axis: float
    """Direction of its long axis (a square: one side; a round object: the board's x)."""
    centre: np.ndarray


def measured_shape(outline_m: np.ndarray) -> Shape:
    """The object's kind and own axes from its footprint: a long object's axis is its area's
    principal axis (a bent eggplant's smallest enclosing rectangle is turned 6-10 degrees off
    its length), a square's the sides of that rectangle, a round object's the image's.

    Args:
        outline_m: (n, 2) the object's footprint on the board, metres.

    Returns:
        Its kind, the direction of its own axis (radians) and its centre (2,), metres.
    """
    import cv2

    from keymps.designs.crop_shape import classify
    from keymps.designs.outline import polygon_centroid

    polygon = 1000.0 * np.asarray(outline_m, float)
    kind, angle = classify(polygon)
    if kind == "elongated":
        moments = cv2.moments(polygon.astype(np.float32))
        angle = 0.5 * math.atan2(2 * moments["mu11"], moments["mu20"] - moments["mu02"])
    return Shape(kind, 0.0 if kind == "round" else angle, polygon_centroid(polygon) / 1000.0)


def cut_angle(cut: CutEffect) -> float:
    """The direction of a cut's line (radians, board frame), from its severed stretches."""
    ends = cut.severed_m.reshape(-1, 2)
    start, end = ends[0], ends[-1]
    return math.atan2(float(end[1] - start[1]), float(end[0] - start[0]))


def line_gap(a: float, b: float) -> float:
    """The angle between two lines (directions modulo 180 degrees), 0 to pi / 2 radians."""
    return abs(math.remainder(a - b, math.pi))
