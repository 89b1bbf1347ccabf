"""Measure the object in the crop: its footprint in millimetres, and whether it is round, square
or elongated (what the offline planner needs to lay out a design)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from keymps.designs.body import body_ends
from keymps.designs.outline import (
    Outline,
    ShapeKind,
    clip_to_slab,
    polygon_area,
    polygon_centroid,
)
from keymps.sorted_values import median

ELONGATED_ASPECT = 1.35
"""Length / width at or above which an object is elongated (a loaf, an eggplant)."""
SQUARE_FILL = 0.89
"""Area / bounding-rectangle area above which a compact object is square (a disk fills 0.785)."""
BACKGROUND_THRESHOLD = 30
"""Colour difference from the crop's border colour that marks the object (0-255)."""


@dataclass(frozen=True)
class CropShape:
    """The object's footprint in a millimetre frame aligned with the crop (x right, y down)."""

    outline: Outline
    """The body's footprint: the whole object, or a long one without an end of another colour
    (keymps.designs.body)."""
    mm_per_px: tuple[float, float]
    source: str
    """'mask' (the detector's), 'segmented' (found in the crop) or 'crop' (the whole crop)."""
    trimmed_mm: tuple[float, float] = (0.0, 0.0)
    """Length left out at the low and the high end of the long axis (a cap, a stem), mm."""

    def to_pixels(self, points_mm: np.ndarray) -> np.ndarray:
        return np.asarray(points_mm, float) / np.array(self.mm_per_px)

    def to_mm(self, points_px: np.ndarray) -> np.ndarray:
        return np.asarray(points_px, float) * np.array(self.mm_per_px)

    def describe(self) -> str:
        o = self.outline
        if o.kind == "round":
            return f"round object, about {2 * o.radius / 10:.1f} cm across"
        left_out = sum(self.trimmed_mm)
        body = f" without {left_out / 10:.1f} cm of another colour at its end (a cap or a stem)"
        return f"{o.kind} object, about {o.length / 10:.1f} x {o.width / 10:.1f} cm" + (
            body if left_out else ""
        )


def segment_crop(crop: np.ndarray) -> np.ndarray | None:
    """A boolean mask of the object: pixels that differ from the crop's border colour."""
    import cv2

    image = crop if crop.ndim == 3 else cv2.cvtColor(crop, cv2.COLOR_GRAY2BGR)
    blurred = cv2.GaussianBlur(image, (5, 5), 0).astype(np.int16)
    border = np.concatenate(
        [blurred[0], blurred[-1], blurred[:, 0], blurred[:, -1]], axis=0
    ).reshape(-1, blurred.shape[2])
    background = median(border, axis=0)
    difference = np.abs(blurred - background).max(axis=2)
    mask = difference > BACKGROUND_THRESHOLD
    if mask.sum() < 0.01 * mask.size:
        return None
    return np.asarray(mask)


def _largest_contour(mask: np.ndarray) -> np.ndarray | None:
    import cv2

    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    largest = max(contours, key=cv2.contourArea)
    if cv2.contourArea(largest) < 9:
        return None
    return np.asarray(largest.reshape(-1, 2), dtype=float)


SQUARE_SNAP_DEG = 0.5
"""A square footprint measured within this of the image axes is taken as aligned with them."""
ELONGATED_SNAP_DEG = 0.1
"""An elongated one's axis within this of the image axes is taken as aligned: its second
moments place it to a few hundredths of a degree, so this is pixel noise only."""


def classify(polygon_mm: np.ndarray) -> tuple[ShapeKind, float]:
    """(kind, long-axis angle) of a footprint polygon in metric units."""
    import cv2

    (_, _), (w, h), angle_deg = cv2.minAreaRect(polygon_mm.astype(np.float32))
    long_side, short_side = max(w, h), max(min(w, h), 1e-9)
    angle = math.radians(angle_deg) if w >= h else math.radians(angle_deg + 90)
    angle = math.atan2(math.sin(angle), math.cos(angle))
    # fold to (-pi/2, pi/2]: a cut axis has no sign
    if angle <= -math.pi / 2:
        angle += math.pi
    elif angle > math.pi / 2:
        angle -= math.pi
    aspect = long_side / short_side
    fill = polygon_area(polygon_mm) / max(w * h, 1e-9)
    if aspect >= ELONGATED_ASPECT:
        kind: ShapeKind = "elongated"
        angle = _principal_axis(polygon_mm)
    elif fill >= SQUARE_FILL:
        kind = "square"
    else:
        kind = "round"
    # Keep the image axes when the sides nearly align with them: for a round object within 10
    # degrees (its rectangle's angle means little), for others within measurement noise only
    # (a cake turned 3 degrees must get a turned grid, or its pieces are 5 % unequal).
    snap = math.radians(
        {"round": 10.0, "square": SQUARE_SNAP_DEG, "elongated": ELONGATED_SNAP_DEG}[kind]
    )
    near_vertical = abs(abs(angle) - math.pi / 2) < snap
    if abs(angle) < snap or (near_vertical and kind != "elongated"):
        angle = 0.0
    elif near_vertical:  # a long object standing upright: its long axis is the image's y
        angle = math.pi / 2
    return kind, angle


def _principal_axis(polygon_mm: np.ndarray) -> float:
    """The footprint's long axis from its second moments of area, in (-pi/2, pi/2]: the
    minimum-area rectangle of an oval or a curved body is a degree or more off."""
    import cv2

    moments = cv2.moments(polygon_mm.astype(np.float32))
    angle = 0.5 * math.atan2(2 * moments["mu11"], moments["mu20"] - moments["mu02"])
    return angle + math.pi if angle <= -math.pi / 2 else angle


def measure(crop: np.ndarray, mask: np.ndarray | None, mm_per_px: tuple[float, float]) -> CropShape:
    """The object's footprint from the detector's mask, else from the crop's own pixels."""
    source = "mask"
    if mask is None or mask.shape[:2] != crop.shape[:2] or not mask.any():
        mask = segment_crop(crop)
        source = "segmented"
    contour = _largest_contour(mask) if mask is not None else None
    height, width = crop.shape[:2]
    if contour is None:
        contour = np.array(
            [[0, 0], [width - 1, 0], [width - 1, height - 1], [0, height - 1]], float
        )
        source = "crop"
    # pixel centres of boundary pixels lie half a pixel inside the true edge
    polygon_mm = _grow_half_pixel(contour) * np.array(mm_per_px)
    kind, angle = classify(polygon_mm)
    outline = Outline(
        kind=kind, polygon=polygon_mm, centre=polygon_centroid(polygon_mm), axis_angle=angle
    )
    shape = CropShape(outline=outline, mm_per_px=mm_per_px, source=source)
    return _body_only(shape, crop, mask) if kind == "elongated" and mask is not None else shape


def _body_only(shape: CropShape, crop: np.ndarray, mask: np.ndarray) -> CropShape:
    """A long object's shape without an end of another colour (its cap and stem)."""
    from dataclasses import replace

    o = shape.outline
    ends = body_ends(crop, mask, shape.mm_per_px, o.centre, o.axis_angle, o.extent(o.axis_angle))
    if ends is None:
        return shape
    polygon = clip_to_slab(o.polygon, o.centre, o.axis_angle, ends.low, ends.high)
    body = replace(o, polygon=polygon, centre=polygon_centroid(polygon))
    return replace(shape, outline=body, trimmed_mm=(ends.trimmed_low, ends.trimmed_high))


def _grow_half_pixel(contour: np.ndarray) -> np.ndarray:
    centre = contour.mean(axis=0)
    offsets = contour - centre
    distance = np.maximum(np.linalg.norm(offsets, axis=1), 1e-9)
    return centre + offsets * ((distance + 0.5) / distance)[:, None]
