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
    regions = Regions(outline_m, cuts_m, hole_m, resolution_m)
    return sorted(regions.areas_m2.tolist(), reverse=True), regions.object_area_m2


class Regions:
    """The object's outline (and hole) rasterized at `resolution_m`, cut by one-pixel barriers
    along the cuts (each lengthened by `reach_m` at both ends): its 4-connected regions."""

    def __init__(
        self,
        outline_m: np.ndarray,
        cuts_m: np.ndarray,
        hole_m: np.ndarray | None = None,
        resolution_m: float = RESOLUTION_M,
        reach_m: float = REACH_M,
    ):
        import cv2

        outline = np.asarray(outline_m, dtype=float)
        cuts = np.asarray(cuts_m, dtype=float).reshape(-1, 2, 2)
        self.resolution_m = resolution_m
        self.origin = outline.min(axis=0) - 4 * resolution_m
        size = np.ceil((outline.max(axis=0) - self.origin) / resolution_m).astype(int) + 4
        mask = np.zeros((int(size[1]), int(size[0])), dtype=np.uint8)
        cv2.fillPoly(mask, [self._px(outline)], 1)
        if hole_m is not None and len(hole_m) >= 3:
            cv2.fillPoly(mask, [self._px(np.asarray(hole_m, dtype=float))], 0)
        pixel_area = resolution_m**2
        self.object_area_m2 = cv2.countNonZero(mask) * pixel_area
        for start, end in cuts:
            length = float(np.linalg.norm(end - start))
            if length > 0:
                reach = reach_m * (end - start) / length
                start, end = start - reach, end + reach
            a, b = self._px(start), self._px(end)
            cv2.line(mask, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), 0, 1, cv2.LINE_8)
        _, self.labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=4)
        self.boxes = stats[1:, :4]
        """Per region, its bounding box in cells: left, top, width, height."""
        self.areas_m2 = stats[1:, cv2.CC_STAT_AREA].astype(float) * pixel_area
        """Area of region i (label i + 1; label 0 is outside the object and the barriers)."""

    def _px(self, points: np.ndarray) -> np.ndarray:
        return np.round((points - self.origin) / self.resolution_m).astype(np.int32)

    def outline(self, region: int) -> np.ndarray:
        """(n, 2) the outline of region `region` (0-based, as `areas_m2`), in the outline's
        frame, simplified to within a raster cell."""
        import cv2

        left, top, width, height = (int(v) for v in self.boxes[region])
        box = self.labels[top : top + height, left : left + width]
        inside = np.pad((box == region + 1).astype(np.uint8), 1)  # contours need a border
        contours, _ = cv2.findContours(inside, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        largest = max(contours, key=cv2.contourArea)
        simple = cv2.approxPolyDP(largest, 1.0, True).reshape(-1, 2) + [left - 1, top - 1]
        return simple.astype(float) * self.resolution_m + self.origin


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
