"""Object footprints (Outline) and the plane geometry the designs are built from.

Units are free (the offline planner uses millimetres); x right, y down, angles in radians from
+x towards +y, so -pi/2 points to the top of the image.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

ShapeKind = Literal["round", "square", "elongated"]
PointLike = Sequence[float] | np.ndarray
Values = Sequence[float] | np.ndarray

TOP = -math.pi / 2
"""The direction of the image's top edge (y grows downwards)."""


@dataclass(frozen=True)
class Outline:
    """An object's footprint: a closed boundary polygon, its centre and principal axes."""

    kind: ShapeKind
    polygon: np.ndarray
    """(N, 2) boundary vertices in order (not repeated at the end)."""
    centre: np.ndarray
    """(2,) area centroid."""
    axis_angle: float
    """Direction of the long axis (for a square: one side's direction)."""

    @property
    def axis(self) -> np.ndarray:
        return direction(self.axis_angle)

    def extent(self, angle: float) -> tuple[float, float]:
        """(min, max) of the boundary projected on the line through the centre at `angle`."""
        offsets = (self.polygon - self.centre) @ direction(angle)
        return float(offsets.min()), float(offsets.max())

    @property
    def length(self) -> float:
        low, high = self.extent(self.axis_angle)
        return high - low

    @property
    def width(self) -> float:
        low, high = self.extent(self.axis_angle + math.pi / 2)
        return high - low

    @property
    def area(self) -> float:
        return polygon_area(self.polygon)

    @property
    def radius(self) -> float:
        """Radius of the circle with the same area."""
        return math.sqrt(self.area / math.pi)

    def inner_radius(self) -> float:
        """Distance from the centre to the nearest boundary point."""
        return float(_distance_to_polygon(self.centre, self.polygon))


def direction(angle: float) -> np.ndarray:
    return np.array([math.cos(angle), math.sin(angle)])


def polygon_area(polygon: np.ndarray) -> float:
    x, y = polygon[:, 0], polygon[:, 1]
    return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2.0)


def polygon_centroid(polygon: np.ndarray) -> np.ndarray:
    x, y = polygon[:, 0], polygon[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    area = cross.sum() / 2.0
    if abs(area) < 1e-12:
        return np.asarray(polygon.mean(axis=0), dtype=float)
    cx = ((x + np.roll(x, -1)) * cross).sum() / (6.0 * area)
    cy = ((y + np.roll(y, -1)) * cross).sum() / (6.0 * area)
    return np.array([cx, cy])


def circle_polygon(centre: PointLike, radius: float, vertices: int = 720) -> np.ndarray:
    angles = np.linspace(0.0, 2 * math.pi, vertices, endpoint=False)
    return np.asarray(centre, float) + radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)


def rectangle_polygon(
    centre: PointLike, length: float, width: float, angle: float = 0.0
) -> np.ndarray:
    u, v = direction(angle), direction(angle + math.pi / 2)
    corners = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
    c = np.asarray(centre, float)
    return np.array([c + a * length / 2 * u + b * width / 2 * v for a, b in corners])


def _distance_to_polygon(point: np.ndarray, polygon: np.ndarray) -> float:
    a, b = polygon, np.roll(polygon, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", point - a, ab) / np.maximum((ab**2).sum(axis=1), 1e-12), 0, 1)
    nearest = a + t[:, None] * ab
    return float(np.sqrt(((nearest - point) ** 2).sum(axis=1)).min())


def line_hits(outline: Outline, point: np.ndarray, dirn: np.ndarray) -> np.ndarray:
    """Parameters t where the line point + t * dirn crosses the outline's boundary (sorted)."""
    a = outline.polygon
    edge = np.roll(a, -1, axis=0) - a
    denom = dirn[0] * edge[:, 1] - dirn[1] * edge[:, 0]
    ok = np.abs(denom) > 1e-12
    diff = a - point
    t = np.where(
        ok, (diff[:, 0] * edge[:, 1] - diff[:, 1] * edge[:, 0]) / np.where(ok, denom, 1), 0
    )
    u = np.where(ok, (diff[:, 0] * dirn[1] - diff[:, 1] * dirn[0]) / np.where(ok, denom, 1), -1)
    hit = ok & (u >= -1e-9) & (u <= 1 + 1e-9)
    return np.sort(t[hit])


def chord(
    outline: Outline, point: np.ndarray, angle: float, overshoot: float = 0.0
) -> np.ndarray | None:
    """The cut through `point` along `angle` across the whole object, extended by `overshoot`."""
    dirn = direction(angle)
    hits = line_hits(outline, np.asarray(point, float), dirn)
    if len(hits) < 2 or hits[-1] - hits[0] < 1e-9:
        return None
    start = point + (hits[0] - overshoot) * dirn
    end = point + (hits[-1] + overshoot) * dirn
    return np.array([start, end])


def ray(outline: Outline, origin: np.ndarray, angle: float, overshoot: float = 0.0) -> np.ndarray:
    """A cut from `origin` (inside the object) outwards along `angle` to beyond the boundary."""
    dirn = direction(angle)
    hits = line_hits(outline, np.asarray(origin, float), dirn)
    ahead = hits[hits > 1e-9]
    reach = float(ahead.max()) if len(ahead) else 0.0
    return np.array([origin, origin + (reach + overshoot) * dirn])


def clip_to_slab(polygon: np.ndarray, point: np.ndarray, angle: float, low: float, high: float):
    """The polygon's part where (p - point) . direction(angle) lies in [low, high]."""
    axis = direction(angle)
    for limit, sign in ((low, 1.0), (high, -1.0)):
        polygon = _clip_half_plane(polygon, sign * ((polygon - point) @ axis - limit))
    return polygon


def _clip_half_plane(polygon: np.ndarray, side: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman: keep the part where the signed `side` of each vertex is >= 0."""
    kept = []
    count = len(polygon)
    for i in range(count):
        a, b = polygon[i], polygon[(i + 1) % count]
        sa, sb = side[i], side[(i + 1) % count]
        if sa >= 0:
            kept.append(a)
        if (sa >= 0) != (sb >= 0):
            kept.append(a + (b - a) * (sa / (sa - sb)))
    return np.asarray(kept, dtype=float).reshape(-1, 2)


INSET_CELLS = 600
"""inset_polygon's raster: this many cells across the polygon's larger extent (0.25 mm on a
15 cm cake); the inset boundary is placed to a cell at worst, half a cell on average."""
INSET_SIMPLIFY_CELLS = 1.5
"""The inset boundary's staircase is straightened to within this many cells (its arc length,
along which dots are spaced, is then the smooth curve's)."""


def inset_polygon(polygon: np.ndarray, distance: float) -> np.ndarray:
    """The boundary of the points at least `distance` inside `polygon` (a rounded corner stays
    rounded, a wavy side is followed), to 1/600 of the polygon's size.

    Args:
        polygon: (N, 2) a simple polygon's vertices in order, any planar units.
        distance: How far inside, the polygon's units (> 0).

    Returns:
        (M, 2) the inset boundary, with the positive shoelace orientation (clockwise as seen in
        an image, y down); the largest part where the inside splits.

    Raises:
        ValueError: No point lies that far inside.
    """
    import cv2

    ring = np.asarray(polygon, float).reshape(-1, 2)
    low = ring.min(axis=0)
    cell = max(float(np.ptp(ring, axis=0).max()), 1e-12) / INSET_CELLS
    pad = 2
    columns, rows = (np.ceil(np.ptp(ring, axis=0) / cell).astype(int) + 2 * pad + 1).tolist()
    inside = np.zeros((rows, columns), np.uint8)
    pixels = (ring - low) / cell + pad  # a cell's centre at whole coordinates
    cv2.fillPoly(inside, [np.round(pixels * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
    # each inside cell's centre to the nearest outside cell's centre; the edge lies half a
    # cell short of it. Cells whose centre is within half a cell of `distance` bound the result.
    reach = cv2.distanceTransform(inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) - 0.5
    kept = (reach >= distance / cell - 0.5).astype(np.uint8)
    contours, _ = cv2.findContours(kept, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise ValueError("inset larger than the object")
    largest = max(contours, key=cv2.contourArea)
    straight = cv2.approxPolyDP(largest, INSET_SIMPLIFY_CELLS, True).reshape(-1, 2)
    path = (straight.astype(float) - pad) * cell + low
    return path if _shoelace(path) >= 0 else path[::-1].copy()


def _shoelace(polygon: np.ndarray) -> float:
    """Twice the signed area (positive: x towards y)."""
    x, y = polygon[:, 0], polygon[:, 1]
    return float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def as_pairs(pairs: Sequence[np.ndarray]) -> np.ndarray:
    if not pairs:
        return np.zeros((0, 2, 2))
    return np.asarray(np.stack(pairs), dtype=float).reshape(-1, 2, 2)
