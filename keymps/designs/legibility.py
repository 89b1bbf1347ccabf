"""Whether an icing drawing stays legible with the tool's line: strokes that would merge."""

from __future__ import annotations

import math

import numpy as np

MERGE_PATH_FACTOR = 4.0
"""Two points of a drawing closer than a line width merge unless the line itself joins them
within this many line widths (a corner, a star's tip: the line is meant to meet itself)."""


def merging_strokes(pairs: np.ndarray, line_width: float) -> tuple[float, np.ndarray] | None:
    """Where a line of `line_width` drawn along every pair (each a stroke, a zero-length pair a
    dot) would run into another part of the drawing: (their distance, the midpoint), or None.

    Points of the strokes, sampled a quarter of a line width apart, merge when closer than the
    line width while more than MERGE_PATH_FACTOR line widths apart along the drawing (through
    strokes that share an end); strokes that cross are meant to. Returned is the closest such
    pair of points.
    """
    pairs = np.asarray(pairs, float).reshape(-1, 2, 2)
    if len(pairs) == 0 or line_width <= 0:
        return None
    ends = pairs.reshape(-1, 2)
    nodes, node_of = _unique_points(ends, 1e-6 * max(1.0, float(np.abs(ends).max())))
    lengths = np.linalg.norm(pairs[:, 1] - pairs[:, 0], axis=1)
    between = np.full((len(nodes), len(nodes)), np.inf)
    np.fill_diagonal(between, 0.0)
    for k, length in enumerate(lengths):
        a, b = node_of[2 * k], node_of[2 * k + 1]
        between[a, b] = between[b, a] = min(between[a, b], length)
    for k in range(len(nodes)):  # Floyd-Warshall: path lengths through shared ends
        between = np.minimum(between, between[:, k : k + 1] + between[k : k + 1, :])
    step = line_width / 4
    samples = [np.linspace(0.0, 1.0, max(2, math.ceil(length / step) + 1)) for length in lengths]
    points = [p[0] + f[:, None] * (p[1] - p[0]) for p, f in zip(pairs, samples, strict=True)]
    along = [f * length for f, length in zip(samples, lengths, strict=True)]
    best: tuple[float, np.ndarray] | None = None
    far = MERGE_PATH_FACTOR * line_width
    for i, j in _near_pairs(pairs, line_width):  # in the order of loops over i < j
        gaps = np.linalg.norm(points[i][:, None, :] - points[j][None, :, :], axis=2)
        if gaps.min() >= line_width or _cross(pairs[i], pairs[j]):
            continue  # lines that cross are drawn to (a pentagram's), not merging
        ui, uj = along[i][:, None], along[j][None, :]
        ri, rj = lengths[i] - ui, lengths[j] - uj
        ai, bi, aj, bj = node_of[2 * i], node_of[2 * i + 1], node_of[2 * j], node_of[2 * j + 1]
        path = np.minimum.reduce(
            [ui + between[ai, aj] + uj, ui + between[ai, bj] + rj,
             ri + between[bi, aj] + uj, ri + between[bi, bj] + rj]
        )  # fmt: skip
        merging = (gaps < line_width) & (path > far)
        if merging.any():
            gap = float(gaps[merging].min())
            if best is None or gap < best[0]:
                a, b = np.argwhere(merging & (gaps == gap))[0]
                best = (gap, (points[i][a] + points[j][b]) / 2)
    return best


def _cross(first: np.ndarray, second: np.ndarray) -> bool:
    """True when two segments cross at a point inside both (not at an end)."""
    (a, b), (c, d) = first, second

    def side(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> float:
        return float((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))

    return side(a, b, c) * side(a, b, d) < 0 and side(c, d, a) * side(c, d, b) < 0


def _near_pairs(pairs: np.ndarray, line_width: float) -> np.ndarray:
    """(i, j), i < j in row order: the strokes whose bounding boxes come closer than the line
    width. The boxes' distance is a lower bound of every gap between the strokes' points, so
    the strokes left out are exactly ones with no gap under the line width (the margin covers
    rounding in the sampled points)."""
    low, high = pairs.min(axis=1), pairs.max(axis=1)
    apart = np.maximum(low[:, None, :] - high[None, :, :], low[None, :, :] - high[:, None, :])
    box_gap = np.linalg.norm(np.maximum(apart, 0.0), axis=2)
    return np.argwhere(np.triu(box_gap < line_width * (1.0 + 1e-9), k=1))


def _unique_points(points: np.ndarray, tolerance: float) -> tuple[np.ndarray, list[int]]:
    """The distinct points (within tolerance) and, per input point, the index of its own: the
    first point of a group within tolerance of it stands for the group."""
    close = np.abs(points[:, None, :] - points[None, :, :]).max(axis=2) <= tolerance
    nodes: list[int] = []
    index: list[int] = []
    for i in range(len(points)):
        for k, node in enumerate(nodes):
            if close[node, i]:
                index.append(k)
                break
        else:
            nodes.append(i)
            index.append(len(nodes) - 1)
    return points[nodes], index
