"""Appendix F's success test: do the cut lines split the object into N pieces of equal area?

The object's outline (and hole) is rasterized at RESOLUTION_M, the cut lines are drawn across
it as one-pixel barriers, and the pieces are the 4-connected regions left (OpenCV
connectedComponents). At 0.1 mm a barrier removes about 0.1 mm times its length from the area,
under 0.5 % of a sixth of a 12 cm cake, well inside the 5 % tolerance. Regions smaller than
CRUMB_FRACTION of the object (where three cuts nearly meet at the centre) are crumbs, not pieces.
Each cut is lengthened by REACH_M at both ends before it is drawn: a blade about a millimetre
thick severs a piece whose cut line stops a fraction of a millimetre short of the edge, and the
raster cannot tell such a cut from one that crosses the edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RESOLUTION_M = 0.0001
CRUMB_FRACTION = 0.01
REACH_M = 0.0005


@dataclass(frozen=True)
class PartsCheck:
    """The pieces a set of cut lines leaves, and whether they are the N equal parts asked for."""

    areas_m2: tuple[float, ...]
    """Areas of the pieces, largest first (crumbs excluded)."""
    object_area_m2: float
    parts: int
    tolerance: float
    crumbs: int

    @property
    def ideal_m2(self) -> float:
        return self.object_area_m2 / self.parts

    @property
    def worst_deviation(self) -> float:
        """Largest |area - ideal| / ideal over the pieces (inf when the count is wrong)."""
        if len(self.areas_m2) != self.parts:
            return float("inf")
        return float(max(abs(a - self.ideal_m2) / self.ideal_m2 for a in self.areas_m2))

    @property
    def ok(self) -> bool:
        return len(self.areas_m2) == self.parts and self.worst_deviation <= self.tolerance

    def describe(self) -> str:
        if len(self.areas_m2) != self.parts:
            return f"{len(self.areas_m2)} pieces, not {self.parts}"
        return (
            f"{self.parts} pieces, worst {100 * self.worst_deviation:.1f} % off an equal share"
            f" (limit {100 * self.tolerance:g} %)"
        )


def split_areas(
    outline_m: np.ndarray,
    cuts_m: np.ndarray,
    hole_m: np.ndarray | None = None,
    resolution_m: float = RESOLUTION_M,
) -> tuple[list[float], float]:
    """(areas of the regions the cuts leave, the object's area), both in m^2, regions largest
    first. Cuts are (K, 2, 2) segments in the outline's frame (metres, y up or down alike)."""
    import cv2

    outline = np.asarray(outline_m, dtype=float)
    cuts = np.asarray(cuts_m, dtype=float).reshape(-1, 2, 2)
    origin = outline.min(axis=0) - 4 * resolution_m
    size = np.ceil((outline.max(axis=0) - origin) / resolution_m).astype(int) + 4

    def to_px(points: np.ndarray) -> np.ndarray:
        return np.round((points - origin) / resolution_m).astype(np.int32)

    mask = np.zeros((int(size[1]), int(size[0])), dtype=np.uint8)
    cv2.fillPoly(mask, [to_px(outline)], 1)
    if hole_m is not None and len(hole_m) >= 3:
        cv2.fillPoly(mask, [to_px(np.asarray(hole_m, dtype=float))], 0)
    object_pixels = cv2.countNonZero(mask)
    for start, end in cuts:
        length = float(np.linalg.norm(end - start))
        if length > 0:
            reach = REACH_M * (end - start) / length
            start, end = start - reach, end + reach
        a, b = to_px(start), to_px(end)
        cv2.line(mask, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), 0, 1, cv2.LINE_8)
    count, labels = cv2.connectedComponents(mask, connectivity=4)
    pixels = np.bincount(labels.ravel(), minlength=count)[1:]
    pixel_area = resolution_m**2
    return sorted((float(p) * pixel_area for p in pixels), reverse=True), object_pixels * pixel_area


def check_equal_parts(
    outline_m: np.ndarray,
    cuts_m: np.ndarray,
    parts: int,
    tolerance: float = 0.05,
    hole_m: np.ndarray | None = None,
) -> PartsCheck:
    """Whether `cuts_m` split the object into `parts` pieces each within `tolerance` of an
    equal share of its area."""
    areas, total = split_areas(outline_m, cuts_m, hole_m)
    pieces = [a for a in areas if a >= CRUMB_FRACTION * total]
    return PartsCheck(
        areas_m2=tuple(pieces),
        object_area_m2=total,
        parts=parts,
        tolerance=tolerance,
        crumbs=len(areas) - len(pieces),
    )
