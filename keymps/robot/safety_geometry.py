"""Distances the safety check measures: points to a polyline (the planned path) and points
outside a polygon (the object's footprint). The simulator measures with the same functions."""

from __future__ import annotations

import numpy as np


def _segment_distances(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances of points (n, 3) to segments a[i]-b[i] given per point: (n, k, 3) each."""
    ab = b - a
    length2 = np.maximum((ab**2).sum(axis=-1), 1e-18)
    t = np.clip(((points[:, None, :] - a) * ab).sum(axis=-1) / length2, 0.0, 1.0)
    gap = points[:, None, :] - (a + t[..., None] * ab)
    return np.sqrt((gap**2).sum(axis=-1))


def _brute_force(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    a, b = polyline[:-1][None], polyline[1:][None]
    out = np.empty(len(points))
    chunk = max(1, 1_000_000 // (len(polyline) - 1))
    for start in range(0, len(points), chunk):
        block = points[start : start + chunk]
        out[start : start + chunk] = _segment_distances(block, a, b).min(axis=1)
    return out


BLOCK_SEGMENTS = 8
"""Consecutive segments bounded together by one box in the pruned search (small: sawing
strokes run over each other, and every overlapping block must be searched)."""


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Exact distance of each point (n, 3) to a polyline (m, 3)."""
    points = np.asarray(points, dtype=float)
    polyline = np.asarray(polyline, dtype=float)
    if len(polyline) == 1 or len(points) == 0:
        return np.linalg.norm(points - polyline[0], axis=1)
    segments = len(polyline) - 1
    if segments <= 2 * BLOCK_SEGMENTS or segments * len(points) <= 50_000:
        return _brute_force(points, polyline)
    return _pruned(points, polyline)


def _pruned(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Branch and bound over blocks of BLOCK_SEGMENTS segments, each inside a box: the
    distance to a block is at least the distance to its box, so only blocks whose bound is
    below the best distance found in the most promising block can hold the nearest segment."""
    segments = len(polyline) - 1
    blocks = -(-segments // BLOCK_SEGMENTS)
    first = np.arange(blocks) * BLOCK_SEGMENTS
    last = np.minimum(first + BLOCK_SEGMENTS, segments)  # vertex index ending each block
    low = np.minimum.reduceat(polyline[:-1], first, axis=0)
    high = np.maximum.reduceat(polyline[1:], first, axis=0)
    low = np.minimum(low, np.minimum.reduceat(polyline[1:], first, axis=0))
    high = np.maximum(high, np.maximum.reduceat(polyline[:-1], first, axis=0))
    out = np.empty(len(points))
    chunk = max(1, 100_000 // blocks)
    for start in range(0, len(points), chunk):
        block_points = points[start : start + chunk, None, :]
        gap = np.maximum(np.maximum(low - block_points, block_points - high), 0.0)
        bound = np.sqrt((gap**2).sum(axis=2))
        block_points = block_points[:, 0]
        best = _block_distances(block_points, polyline, np.argmin(bound, axis=1), last)
        # Row-major: the pairs come grouped by point, and every point has its own best block.
        pairs_point, pairs_block = np.nonzero(bound <= best[:, None])
        found = _block_distances(block_points[pairs_point], polyline, pairs_block, last)
        starts = np.flatnonzero(np.diff(pairs_point, prepend=-1))
        out[start : start + chunk] = np.minimum.reduceat(found, starts)
    return out


def _block_distances(
    points: np.ndarray, polyline: np.ndarray, blocks: np.ndarray, last: np.ndarray
) -> np.ndarray:
    """Distance of points[i] to the segments of block blocks[i]."""
    index = blocks[:, None] * BLOCK_SEGMENTS + np.arange(BLOCK_SEGMENTS)
    index = np.minimum(index, last[blocks][:, None] - 1)  # a short last block repeats its end
    return _segment_distances(points, polyline[index], polyline[index + 1]).min(axis=1)


def outside_distance(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """How far each 2D point lies outside a polygon (0 inside or on it), metres."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    polygon = np.asarray(polygon, dtype=float).reshape(-1, 2)
    if len(points) == 0:
        return np.zeros(0)
    closed = np.vstack([polygon, polygon[:1]])
    flat = np.zeros((len(closed), 3))
    flat[:, :2] = closed
    lifted = np.zeros((len(points), 3))
    lifted[:, :2] = points
    out = np.zeros(len(points))
    outside = ~inside_polygon(points, polygon)
    if outside.any():  # far from the edge inside, where every edge would be a candidate
        out[outside] = distance_to_polyline(lifted[outside], flat)
    return out


def inside_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(n,) whether each 2D point is inside the polygon (even-odd rule; edges count either
    way, which `outside_distance` does not mind: it is 0 on an edge).

    Points are sorted by y, so each edge meets only the points level with it: the work is the
    number of (edge, point) crossings tested, about twice the points for a simple outline."""
    order = np.argsort(points[:, 1], kind="stable")
    ys = points[order, 1]
    a, b = polygon, np.roll(polygon, -1, axis=0)
    low, high = np.minimum(a[:, 1], b[:, 1]), np.maximum(a[:, 1], b[:, 1])
    # An edge straddles a point's level when exactly one end is above it (half-open: low < y).
    first = np.searchsorted(ys, low, side="right")
    last = np.searchsorted(ys, high, side="right")
    counts = np.maximum(last - first, 0)
    edge = np.repeat(np.arange(len(polygon)), counts)
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    sorted_index = np.repeat(first, counts) + offsets
    point = order[sorted_index]
    px, py = points[point, 0], points[point, 1]
    ax, ay, bx, by = a[edge, 0], a[edge, 1], b[edge, 0], b[edge, 1]
    crossing = ax + (py - ay) * (bx - ax) / (by - ay)  # by != ay: a level edge straddles nothing
    crossings = np.bincount(point[px < crossing], minlength=len(points))
    return crossings % 2 == 1
