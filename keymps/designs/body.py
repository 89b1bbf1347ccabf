"""The body of a long object: its length without an end of another colour (a cap, a stem).

An eggplant's green cap and stem are part of its footprint but not of what a cook slices: "cut
it into 4" divides the purple body, and "slice both tips" cuts the cap off at its base. Along
the object's long axis, each slice of the footprint is compared with the colour of its middle;
an end whose slices are mostly of another colour (far beyond the body's own variation:
highlights, freckles, crust) is left out, up to the first slice that is body throughout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from keymps.designs.outline import direction
from keymps.sorted_values import median, percentile

MIN_BODY_DELTA_E = 15.0
"""Lab distance under which a pixel is the body's colour, at least (else 1.5 times the 95th
percentile of the middle's own spread)."""
END_CONTRAST = 2.0
"""An end is of another colour when its median distance to the body's colour is this many
times that threshold."""
BODY_SLICE = 0.95
"""A slice across the axis is body when this fraction of its pixels has the body's colour."""
MAX_END_FRACTION = 0.4
"""An end of another colour longer than this fraction of the object is no cap: nothing is cut
away (a two-coloured object)."""


@dataclass(frozen=True)
class BodyEnds:
    """Where the body ends along the axis (mm from the footprint's centre), and how much of the
    footprint lies beyond it at each end."""

    low: float
    high: float
    trimmed_low: float
    trimmed_high: float


def body_ends(
    crop: np.ndarray,
    mask: np.ndarray,
    mm_per_px: tuple[float, float],
    centre_mm: np.ndarray,
    axis_angle: float,
    extent: tuple[float, float],
) -> BodyEnds | None:
    """The body's ends along `axis_angle`, or None when no end is of another colour.

    Args:
        crop: (H, W, 3) BGR crop.
        mask: (H, W) bool, the object's pixels in the crop.
        mm_per_px: millimetres per pixel along x and y.
        centre_mm: (2,) the footprint's centre in crop millimetres.
        axis_angle: the long axis, radians from +x towards +y.
        extent: (low, high) of the footprint along the axis from the centre, mm.
    """
    import cv2

    inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    ys, xs = np.nonzero(inner)
    if len(xs) < 200 or crop.ndim != 3:
        return None
    lab = cv2.cvtColor(crop.astype(np.float32) / 255.0, cv2.COLOR_BGR2Lab)[ys, xs]
    points = (np.stack([xs, ys], axis=1) + 0.5) * np.asarray(mm_per_px)
    along = (points - centre_mm) @ direction(axis_angle)
    low, high = extent
    length = high - low
    middle = np.abs(along - (low + high) / 2) < 0.2 * length
    if middle.sum() < 50:
        return None
    body = median(lab[middle], axis=0)
    distance = np.linalg.norm(lab - body, axis=1)
    threshold = max(MIN_BODY_DELTA_E, 1.5 * percentile(distance[middle], 95))
    bins = np.linspace(low, high, int(np.clip(length, 20, 400)) + 1)
    slot = np.clip(np.searchsorted(bins, along) - 1, 0, len(bins) - 2)
    pixels = np.bincount(slot, minlength=len(bins) - 1)
    of_body = np.bincount(slot, weights=distance < threshold, minlength=len(bins) - 1)
    cuts = [
        _end(bins, pixels, of_body, distance, slot, threshold, order)
        for order in (range(len(pixels)), range(len(pixels) - 1, -1, -1))
    ]
    body_low = bins[cuts[0]] if cuts[0] is not None else low
    body_high = bins[cuts[1] + 1] if cuts[1] is not None else high
    if cuts == [None, None] or body_high - body_low < (1 - MAX_END_FRACTION) * length:
        return None
    return BodyEnds(body_low, body_high, body_low - low, high - body_high)


def _end(
    bins: np.ndarray,
    pixels: np.ndarray,
    of_body: np.ndarray,
    distance: np.ndarray,
    slot: np.ndarray,
    threshold: float,
    order: range,
) -> int | None:
    """Index of the first slice (walking `order` from one end) that is body throughout, when
    the slices before it are an end of another colour; None when that end is body."""
    for count, index in enumerate(order):
        if pixels[index] >= 3 and of_body[index] >= BODY_SLICE * pixels[index]:
            if count == 0:
                return None
            passed = np.isin(slot, list(order)[:count])
            other = distance[passed & (distance >= threshold)]
            if other.size < 20 or median(other) < END_CONTRAST * threshold:
                return None
            return index
    return None
