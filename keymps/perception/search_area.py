"""The part of an image a detector searches (the whole image, or a polygon) and its sides."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np

from keymps.errors import DetectionError, KeympsError
from keymps.types import Detection

SIDE_NAMES = ("bottom", "right", "top", "left")
"""Names of a four-sided area's sides, in the order of its corners bottom-left, bottom-right,
top-right, top-left (the order of scene.camera.board_corners_px)."""


def roi_polygon(value: Any) -> Any:
    """A detector's `roi` option as a polygon: a box [x0, y0, x1, y1] becomes its corners
    bottom-left, bottom-right, top-right, top-left (SIDE_NAMES' order); a polygon of 3 or more
    points passes as it is (pydantic checks the points). For a `field_validator(mode="before")`."""
    if value is None:
        return None
    if (
        isinstance(value, (list, tuple))
        and len(value) == 4
        and all(isinstance(v, (int, float)) for v in value)
    ):
        x0, y0, x1, y1 = value
        if x1 <= x0 or y1 <= y0:
            raise ValueError(f"a box must be [x0, y0, x1, y1] with x0 < x1, y0 < y1: {value}")
        return [(x0, y1), (x1, y1), (x1, y0), (x0, y0)]
    if not isinstance(value, (list, tuple)) or len(value) < 3:
        raise ValueError("must be a box [x0, y0, x1, y1] or a polygon of 3 or more [x, y] points")
    return value


def comparable_object_warnings(regions: Sequence[Any], pick: int, comparable: float) -> list[str]:
    """A warning per region (with .bbox and .area) at least `comparable` times the area of the
    one at index `pick` (regions by decreasing area): detector.pick may keep the wrong one."""
    # no '#' numbers: the planner numbers the objects it sees (only the picked one here) from
    # the left, while detector.pick counts every region by decreasing area
    chosen = regions[pick]
    return [
        f"detect: detector.pick keeps the object in box {list(chosen.bbox)} "
        f"({chosen.area:.0f} px); another of comparable size, in box {list(region.bbox)} "
        f"({region.area:.0f} px, {_relative_place(region.bbox, chosen.bbox)}), is left out; "
        f"detector.pick: {index} keeps that one (by decreasing area, from 0), and without "
        "detector.pick both are kept for the sentence to choose"
        for index, region in enumerate(regions)
        if index != pick and region.area >= comparable * chosen.area
    ]


def _relative_place(box: Sequence[int], other: Sequence[int]) -> str:
    """'to its right', 'above it' ...: where `box` lies from `other` (image axes, y down)."""
    dx = (box[0] + box[2] - other[0] - other[2]) / 2
    dy = (box[1] + box[3] - other[1] - other[3]) / 2
    if abs(dx) >= abs(dy):
        return "to its right" if dx > 0 else "to its left"
    return "below it" if dy > 0 else "above it"


def odd_kernel(value: int) -> int:
    """A Gaussian kernel size option: odd, or 0 / 1 for no blur."""
    if value > 1 and value % 2 == 0:
        raise ValueError(f"must be odd (a Gaussian kernel size), got {value}")
    return value


@dataclass(frozen=True)
class SearchArea:
    """Made by SearchArea.of, one per image size and polygon: its arrays are read-only, and
    what is derived from them alone (side bands, border bands) is computed once."""

    mask: np.ndarray
    """Bool H x W: the pixels searched."""
    polygon: np.ndarray
    """(N, 2) corners in continuous pixel coordinates."""
    _derived: dict[tuple[str, float], Any] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

    @classmethod
    def of(cls, size_px: tuple[int, int], polygon: list[tuple[float, float]] | None) -> SearchArea:
        """The polygon (continuous pixel coordinates), or the whole image when None."""
        corners = None if polygon is None else np.asarray(polygon, dtype=float).reshape(-1, 2)
        key = None if corners is None else tuple(map(tuple, corners.tolist()))
        return _search_area((int(size_px[0]), int(size_px[1])), key)

    def border_band(self, width_px: int) -> np.ndarray:
        """The searched pixels within width_px of the area's boundary (OpenCV's 3 x 3 L2
        distance to the nearest pixel outside, the image's border counting as outside)."""
        if ("border", width_px) not in self._derived:
            band = self.mask & (self._boundary_distance() <= width_px)
            self._derived["border", width_px] = _read_only(band)
        return self._derived["border", width_px]  # type: ignore[no-any-return]

    def _boundary_distance(self) -> np.ndarray:
        import cv2

        if ("distance", 0) not in self._derived:
            padded = np.pad(self.mask.astype(np.uint8), 1)
            distance = cv2.distanceTransform(padded, cv2.DIST_L2, 3)[1:-1, 1:-1]
            self._derived["distance", 0] = _read_only(distance)
        return self._derived["distance", 0]  # type: ignore[no-any-return]

    @property
    def pixels(self) -> int:
        return int(self.mask.sum())

    def side_names(self) -> list[str]:
        if len(self.polygon) == 4:
            return list(SIDE_NAMES)
        return [f"side {i + 1}" for i in range(len(self.polygon))]

    def side_bands(self, width_px: float = 2.0) -> list[np.ndarray]:
        """Per side, the searched pixels whose centre lies within width_px of that side."""
        if ("sides", width_px) not in self._derived:
            self._derived["sides", width_px] = [_read_only(b) for b in self._side_bands(width_px)]
        return list(self._derived["sides", width_px])

    def _side_bands(self, width_px: float) -> list[np.ndarray]:
        height, width = self.mask.shape
        cols = np.arange(width, dtype=np.float32)[None, :] + 0.5
        rows = np.arange(height, dtype=np.float32)[:, None] + 0.5
        bands = []
        for a, b in zip(self.polygon, np.roll(self.polygon, -1, axis=0), strict=True):
            edge = b - a
            length = max(float(np.hypot(*edge)), 1e-9)
            # Only pixels within the side's box grown by width_px (and a pixel) can be near it.
            x0, y0 = np.maximum(np.floor(np.minimum(a, b) - width_px - 1.5), 0).astype(int)
            x1, y1 = np.maximum(np.ceil(np.maximum(a, b) + width_px + 1.5), 0).astype(int)
            x, y = cols[:, x0:x1], rows[y0:y1]
            t = np.clip(((x - a[0]) * edge[0] + (y - a[1]) * edge[1]) / length**2, 0, 1)
            dx = x - (a[0] + t * edge[0])
            dy = y - (a[1] + t * edge[1])
            band = np.zeros_like(self.mask)
            near = dx * dx + dy * dy <= width_px * width_px
            band[y0:y1, x0:x1] = self.mask[y0:y1, x0:x1] & near
            bands.append(band)
        return bands

    def sides_touched(self, region: np.ndarray, bands: list[np.ndarray] | None = None) -> list[str]:
        """Names of the sides the region (bool H x W) reaches."""
        bands = bands if bands is not None else self.side_bands()
        names = self.side_names()
        return [names[i] for i, band in enumerate(bands) if (region & band).any()]


@lru_cache(maxsize=1)  # the last size and polygon only: its full-size arrays stay in memory
def _search_area(
    size_px: tuple[int, int], corners: tuple[tuple[float, float], ...] | None
) -> SearchArea:
    import cv2

    width, height = size_px
    if corners is None:
        whole = np.array([[0, height], [width, height], [width, 0], [0, 0]], float)
        return SearchArea(_read_only(np.ones((height, width), bool)), _read_only(whole))
    polygon = np.array(corners, dtype=float)
    area = np.zeros((height, width), np.uint8)
    # Pixel centres at +0.5: a polygon vertex (x, y) is index (x - 0.5, y - 0.5).
    points = np.round((polygon - 0.5) * 16).astype(np.int32)
    cv2.fillPoly(area, [points.reshape(-1, 1, 2)], 255, cv2.LINE_8, 4)
    if not area.any():
        raise KeympsError(
            f"detector.roi {polygon.tolist()} lies outside the {width} x {height} px image"
        )
    return SearchArea(_read_only(area > 0), _read_only(polygon))


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


MAX_OBJECT_COVERAGE = 0.75
"""A detected box over this fraction of the image is the board, whatever the detector."""


def refuse_the_board(detection: Detection, size_px: tuple[int, int]) -> Detection:
    """The detection, unless its object is the board: a box touching three or more sides of
    the image, or covering most of it (any detector; the board detector refuses it itself)."""
    width, height = size_px
    x0, y0, x1, y1 = detection.bbox_px
    sides = [
        name
        for name, touching in (
            ("bottom", y1 >= height),
            ("right", x1 >= width),
            ("top", y0 <= 0),
            ("left", x0 <= 0),
        )
        if touching
    ]
    covered = (
        float(np.asarray(detection.mask).sum())
        if detection.mask is not None and detection.mask.shape[:2] == (height, width)
        else float((x1 - x0) * (y1 - y0))
    ) / max(width * height, 1)
    if len(sides) >= 3 or covered > MAX_OBJECT_COVERAGE:
        reason = (
            f"touches {len(sides)} sides of the image ({', '.join(sides)})"
            if len(sides) >= 3
            else f"covers {100 * covered:.0f} % of the image"
        )
        raise DetectionError(
            f"the object found (box {list(detection.bbox_px)}) {reason}: that is the board, not "
            "an object, and nothing is planned on it; use the board detector "
            "(detector: {name: board}), or give scene.camera.board_corners_px or detector.roi",
        )
    return detection
