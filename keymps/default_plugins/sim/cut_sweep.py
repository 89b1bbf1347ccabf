"""What a knife's edge cuts: the board segments its blade covers, and their length in the food.

The blade is a straight horizontal edge at the tip's height in the vertical plane of the tool x
axis, reaching `blade_length` from the tip back against the direction of travel. While the tip is
below the object's top the whole edge is, so the cut is the union of the edge's positions.
"""

from __future__ import annotations

import math

import numpy as np

SWEEP_STEP_M = 0.0005
"""The blade's position is taken each time its tip or far end has moved this far."""
NO_TRAVEL_M = 0.001
"""A work piece moving the tip less than this sideways (a plunge) has no direction of travel:
its blade lies along the tool's -x axis."""
LENGTH_BIN_M = 0.0005
"""Resolution of the measured cut lengths."""
FOOTPRINT_CELL_M = 0.00025
"""Grid cell of the rasterised footprint used to clip the measured cuts."""
CHUNK_POINTS = 8192
"""Blade samples generated at a time when measuring a cut (a few hundred kB of temporaries)."""


def blade_backwards(tool_x: np.ndarray, travel: np.ndarray) -> np.ndarray:
    """(n, 2) unit directions from the tip along the blade: the tool x axis (n, 2), turned to
    point against `travel` (the work piece's horizontal start-to-goal displacement)."""
    if float(np.hypot(*travel)) < NO_TRAVEL_M:
        return -tool_x
    along = tool_x @ np.asarray(travel, dtype=float)
    return tool_x * np.where(along > 0, -1.0, 1.0)[:, None]


def edge_segments(
    tip_xyz: np.ndarray, backwards: np.ndarray | None, blade_length: float
) -> np.ndarray:
    """(k, 2, 2) board segments (tip first) the edge covered over one cut's samples; without a
    blade (`blade_length` 0 or no direction), the tip's path step by step."""
    tip = np.asarray(tip_xyz, dtype=float)[:, :2]
    if blade_length <= 0 or backwards is None:
        return np.stack([tip[:-1], tip[1:]], axis=1)
    far = tip + blade_length * backwards
    keep = _every(np.asarray(tip_xyz, dtype=float), far, SWEEP_STEP_M)
    return np.stack([tip[keep], far[keep]], axis=1)


def _every(tip: np.ndarray, far: np.ndarray, step: float) -> np.ndarray:
    """Indices of the samples where the tip or the far end has moved `step` since the last one,
    plus the first and the last."""
    moved = np.maximum(
        np.linalg.norm(np.diff(tip, axis=0), axis=1), np.linalg.norm(np.diff(far, axis=0), axis=1)
    )
    distance = np.concatenate([[0.0], np.cumsum(moved)])
    bins = np.floor(distance / step)
    keep = np.flatnonzero(np.diff(bins, prepend=-1.0) > 0)
    return np.union1d(keep, [len(tip) - 1])


class Footprint:
    """The object's footprint polygon (board metres; or every object's, a list of polygons),
    rasterised for fast inside tests."""

    def __init__(self, polygon: np.ndarray | list[np.ndarray]):
        import cv2

        polygons = [np.asarray(p, dtype=float).reshape(-1, 2) for p in _polygons(polygon)]
        self.polygon = np.concatenate(polygons)
        self.origin = self.polygon.min(axis=0) - 2 * FOOTPRINT_CELL_M
        cols, rows = np.ceil((self.polygon.max(axis=0) - self.origin) / FOOTPRINT_CELL_M) + 3
        self.mask = np.zeros((int(rows), int(cols)), np.uint8)
        corners = [(p - self.origin) / FOOTPRINT_CELL_M - 0.5 for p in polygons]  # cell centres
        cv2.fillPoly(
            self.mask, [np.round(c * 16).astype(np.int32) for c in corners], 1, cv2.LINE_8, 4
        )
        # A ring of outside cells round the mask: any cell beyond it is clipped onto the ring.
        self._ringed = np.pad(self.mask > 0, 1).ravel()
        self._last_cell = np.array([cols, rows], dtype=float)

    def contains(self, xy: np.ndarray) -> np.ndarray:
        # In place: fresh memory for every temporary costs more than the arithmetic here.
        cells = np.asarray(xy, dtype=float) - self.origin
        cells /= FOOTPRINT_CELL_M
        np.floor(cells, out=cells)
        np.clip(cells, -1.0, self._last_cell, out=cells)
        index = cells.astype(np.intp)
        index += 1
        flat = index[:, 1] * (int(self._last_cell[0]) + 2)
        flat += index[:, 0]
        return self._ringed[flat]


def _polygons(polygon: np.ndarray | list[np.ndarray]) -> list[np.ndarray]:
    return list(polygon) if isinstance(polygon, list) else [np.asarray(polygon)]


def covered_length(segments: np.ndarray, footprint: Footprint | None) -> float:
    """Metres of one cut's line the segments (k, 2, 2) cover, inside the footprint when given."""
    if len(segments) == 0:
        return 0.0
    longest = float(np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1).max())
    fractions = np.linspace(0.0, 1.0, max(2, math.ceil(2 * longest / LENGTH_BIN_M) + 1))
    # Blade positions in chunks of about CHUNK_POINTS samples: fresh memory for large
    # temporaries costs more than the arithmetic; only the points inside are kept.
    step = max(1, CHUNK_POINTS // len(fractions))
    kept = []
    for first in range(0, len(segments), step):
        chunk = segments[first : first + step]
        starts, ends = chunk[:, None, 0], chunk[:, None, 1]
        points = (starts + fractions[None, :, None] * (ends - starts)).reshape(-1, 2)
        kept.append(points[footprint.contains(points)] if footprint is not None else points)
    points = np.concatenate(kept)
    if len(points) < 2:
        return 0.0
    points -= points.mean(axis=0)  # centred
    axis = np.linalg.svd(points, full_matrices=False)[2][0]  # the cut's line
    along = points @ axis
    along /= LENGTH_BIN_M
    bins = np.floor(along, out=along).astype(np.int64)
    occupied = np.count_nonzero(np.bincount(bins - bins.min()))  # len(np.unique(bins))
    return float(occupied * LENGTH_BIN_M)
