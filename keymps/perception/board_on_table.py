"""A board photographed on a darker table looks like one big object: tell it from one.

A photo that shows the table around the board (no scene.camera.board_corners_px) makes the
board detector model the table, and the whole board, object and all, differs from it. Such a
region is four-sided with straight edges, large, and holds another region of its own: inside a
band along its edge of one colour (the board), something of another colour (the object).
"""

from __future__ import annotations

import numpy as np

from keymps.sorted_values import median, percentile

MIN_COVERAGE = 0.1
"""A board fills at least this fraction of the searched area."""
QUAD_FIT = 0.06
"""Its outline is within this fraction of its area of a four-sided polygon (a round or long
object is not)."""
HELD_FRACTION = 0.03
"""Another region inside it of at least this fraction of its area is an object on the board."""
MIN_DELTA_E = 10.0
"""Lab distance from the edge band's colour that marks another region, at least."""


def board_holding_an_object(
    mask: np.ndarray, contour: np.ndarray, coverage: float, lab: np.ndarray
) -> str | None:
    """Why the region is a board on a table with an object on it, or None when it is not.

    Args:
        mask: (H, W) bool, the region's pixels.
        contour: (N, 2) its outline, pixels.
        coverage: the fraction of the searched area it covers.
        lab: (H, W, 3) the image in CIE Lab (float).
    """
    import cv2

    if coverage < MIN_COVERAGE or not _four_sided(contour, float(mask.sum())):
        return None
    ys, xs = np.nonzero(mask)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    region = mask[y0:y1, x0:x1].astype(np.uint8)
    step = max(3, round(0.02 * np.sqrt(region.sum())))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * step + 1, 2 * step + 1))
    inner = cv2.erode(region, kernel)
    core = cv2.erode(inner, kernel, iterations=2) > 0
    band = (inner > 0) & ~core
    colours = lab[y0:y1, x0:x1]
    if band.sum() < 50 or core.sum() < 50:
        return None
    edge_colour = median(colours[band], axis=0)
    distance = np.linalg.norm(colours - edge_colour, axis=2)
    limit = max(MIN_DELTA_E, 3.0 * percentile(distance[band], 75))
    other = (core & (distance > limit)).astype(np.uint8)
    other = cv2.morphologyEx(other, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    count, _, stats, _ = cv2.connectedComponentsWithStats(other, connectivity=8)
    held = int(stats[1:, cv2.CC_STAT_AREA].max()) if count > 1 else 0
    if held < HELD_FRACTION * region.sum():
        return None
    return (
        f"is a four-sided area of {100 * coverage:.0f} % of the searched area, one colour along "
        f"its edge, holding a region of another colour ({held} px): a board on a darker table "
        "with the object on it"
    )


def _four_sided(contour: np.ndarray, area: float) -> bool:
    """Whether the outline is a convex quadrilateral (straight sides, sharp corners)."""
    import cv2

    points = np.asarray(contour, np.float32).reshape(-1, 1, 2)
    approx = cv2.approxPolyDP(points, 0.02 * cv2.arcLength(points, True), True)
    if len(approx) != 4 or not cv2.isContourConvex(approx):
        return False
    return abs(cv2.contourArea(approx) - area) <= QUAD_FIT * area
