"""One primitive rollout along a chain of pairs: a continuous stroke through several pairs.

The path is the chain's polyline with every turn gentler than the timing's corner angle
rounded by a small arc (at most CORNER_ROUNDING_M inside the vertex): the joints cannot follow
a kink at speed (the offline 60-pair spiral, kinks and all, ran 3x slower than
motion.work_speed), and a spiral or ring laid out as short straight pairs is piped as a curve.
Sharper turns stay corners, where the tool stops anyway (a star's tips).

The primitive is re-targeted to a straight segment as long as that path (its own mode, so the
`line` primitive lowers the nozzle at the start, pipes, and lifts it at the end), and the
rollout is bent onto the path: its travel along the segment becomes arc length along the path,
its sideways offsets turn with the path's heading, and heights stay heights. For a straight
chain this is exactly the rollout re-targeted to the chain's ends.
"""

from __future__ import annotations

import math

import numpy as np

from keymps.motion.strokes import CORNER_ANGLE_RAD
from keymps.primitives.dictionary import Primitive

TURN_BLEND_M = 0.002
"""Sideways offsets turn from one segment's heading to the next over this far either side of
a vertex (at most half of either segment): the path stays continuous where a learned primitive
swings sideways across a corner."""
LEVEL_M = 1e-9
"""A segment with less horizontal travel than this has no heading of its own."""
CORNER_ROUNDING_M = 0.0005
"""A gentle turn is rounded by an arc passing at most this far inside its vertex (an eighth of
the piping bag's 4 mm line): invisible in the icing, and the joints follow it at speed."""
CURVE_STEP_M = 0.0005
"""The arcs are sampled at least this finely ..."""
CURVE_TURN_RAD = math.radians(3.0)
"""... and turn at most this much between samples."""


def rollout_along(
    primitive: Primitive,
    vertices: np.ndarray,
    *,
    speed: float,
    spacing: float,
    reach: tuple[float, float] = (math.inf, math.inf),
) -> np.ndarray:
    """The primitive run once along the polyline through `vertices`.

    Args:
        primitive: The primitive (its re-targeting mode decides what stretches).
        vertices: (m + 1, 3) the polyline, board metres; consecutive vertices distinct.
        speed: Average tool speed along the path, m/s.
        spacing: The largest distance between neighbouring rollout samples, metres (about).
        reach: How far the rollout may pass the polyline's start and end along it, metres;
            beyond that it is shortened smoothly (see `limit_along`).

    Returns:
        (n, 3) tool positions, board metres, passing through every vertex.
    """
    path = smooth_path(np.asarray(vertices, dtype=float))
    steps = np.diff(path, axis=0)
    lengths = np.linalg.norm(steps, axis=1)
    arc = np.concatenate([[0.0], np.cumsum(lengths)])
    total = float(arc[-1])
    straight = primitive.rollout(
        np.zeros(3), np.array([total, 0.0, 0.0]), speed=speed, spacing=spacing
    ).y
    along = limit_along(straight[:, 0], total, *reach)
    along, side, up = _through_vertices(along, straight[:, 1], straight[:, 2], arc[1:-1])
    segment = np.clip(np.searchsorted(arc, along, side="right") - 1, 0, len(lengths) - 1)
    fraction = (along - arc[segment]) / np.maximum(lengths[segment], 1e-300)
    points = path[segment] + fraction[:, None] * steps[segment]
    heading = _headings(steps, lengths, along, arc)
    points[:, 0] -= side * np.sin(heading)
    points[:, 1] += side * np.cos(heading)
    points[:, 2] += up
    return points


def smooth_path(vertices: np.ndarray) -> np.ndarray:
    """The path a chain is piped along: its vertices, each turn gentler than CORNER_ANGLE_RAD
    rounded by a circular arc tangent to both segments that passes within CORNER_ROUNDING_M
    of the vertex (and uses at most half of either segment), sampled every CURVE_STEP_M or
    CURVE_TURN_RAD; sharper turns stay corners.

    Args:
        vertices: (m + 1, 3) board metres, consecutive vertices distinct.

    Returns:
        (n, 3) points: the first and last vertex and every sharp corner exactly.
    """
    steps = np.diff(vertices, axis=0)
    lengths = np.linalg.norm(steps, axis=1)
    units = steps / lengths[:, None]
    parts = [vertices[:1]]
    for k in range(1, len(vertices) - 1):
        turn = math.acos(min(1.0, max(-1.0, float(units[k - 1] @ units[k]))))
        if turn >= CORNER_ANGLE_RAD or turn < 1e-9:
            parts.append(vertices[k : k + 1])
            continue
        reach = min(0.5 * lengths[k - 1], 0.5 * lengths[k], CORNER_ROUNDING_M / math.tan(turn / 4))
        parts.append(_arc(vertices[k], units[k - 1], units[k], turn, reach))
    parts.append(vertices[-1:])
    path = np.concatenate(parts)
    keep = np.ones(len(path), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(path, axis=0), axis=1) > 1e-12  # arcs meet mid-segment
    return path[keep]


def _arc(
    vertex: np.ndarray, incoming: np.ndarray, outgoing: np.ndarray, turn: float, reach: float
) -> np.ndarray:
    """Points of the circular arc tangent to the incoming and outgoing directions (units)
    `reach` before and after the vertex, ends included."""
    inward = outgoing - incoming * float(incoming @ outgoing)
    inward /= np.linalg.norm(inward)
    radius = reach / math.tan(turn / 2)
    count = max(1, math.ceil(turn / CURVE_TURN_RAD), math.ceil(radius * turn / CURVE_STEP_M))
    angle = np.linspace(0.0, turn, count + 1)[:, None]
    centre = vertex - reach * incoming + radius * inward
    return centre - radius * np.cos(angle) * inward + radius * np.sin(angle) * incoming


def limit_along(
    along: np.ndarray, length: float, reach_start: float, reach_goal: float
) -> np.ndarray:
    """Positions along a stroke of `length` whose overshoot before 0 and beyond `length` is
    mapped through reach * tanh(overshoot / reach): about the same when small, never beyond
    the reach (identity to second order at the ends)."""
    limited = np.asarray(along, dtype=float).copy()
    before, after = limited < 0.0, limited > length
    limited[before] = -_soft_limit(-limited[before], reach_start)
    limited[after] = length + _soft_limit(limited[after] - length, reach_goal)
    return limited


def _soft_limit(distance: np.ndarray, reach: float) -> np.ndarray:
    """reach * tanh(distance / reach): about `distance` when small, never beyond `reach`."""
    if math.isinf(reach):
        return distance
    if reach <= 0.0:
        return np.zeros_like(distance)
    return reach * np.tanh(distance / reach)


def _through_vertices(
    along: np.ndarray, side: np.ndarray, up: np.ndarray, inner: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples with one inserted wherever `along` crosses an inner vertex's arc length
    (`inner`, ascending; offsets interpolated), in the order it crosses them: the path then
    turns exactly at each vertex, not on a chord across it."""
    low = np.minimum(along[:-1], along[1:])
    high = np.maximum(along[:-1], along[1:])
    first = np.searchsorted(inner, low, side="right")  # strictly inside (low, high)
    stop = np.searchsorted(inner, high, side="left")
    count = np.maximum(stop - first, 0)
    if not count.any():
        return along, side, up
    at = np.repeat(np.arange(len(count)), count)
    offset = np.arange(len(at)) - np.repeat(np.cumsum(count) - count, count)
    rising = along[1:][at] >= along[:-1][at]
    value = inner[np.where(rising, first[at] + offset, stop[at] - 1 - offset)]
    t = (value - along[at]) / (along[at + 1] - along[at])
    inserted = (
        value,
        side[at] + t * (side[at + 1] - side[at]),
        up[at] + t * (up[at + 1] - up[at]),
    )
    along, side, up = (
        np.insert(values, at + 1, extra)
        for values, extra in zip((along, side, up), inserted, strict=True)
    )
    return along, side, up


def _headings(
    steps: np.ndarray, lengths: np.ndarray, along: np.ndarray, arc: np.ndarray
) -> np.ndarray:
    """The direction sideways offsets are measured from at each sample (radians about z):
    each segment's heading, turned linearly over TURN_BLEND_M either side of a vertex."""
    level = np.hypot(steps[:, 0], steps[:, 1])
    raw = np.arctan2(steps[:, 1], steps[:, 0])
    headings: list[float] = []
    for angle, flat in zip(raw.tolist(), level.tolist(), strict=True):
        if flat < LEVEL_M:
            headings.append(headings[-1] if headings else math.nan)
        elif headings and not math.isnan(headings[-1]):
            headings.append(headings[-1] + math.remainder(angle - headings[-1], 2 * math.pi))
        else:
            headings = [angle] * (len(headings) + 1)  # the level ones before take this one
    values = np.nan_to_num(np.array(headings), nan=0.0)
    if len(values) == 1:
        return np.full(len(along), values[0])
    blend = np.minimum(TURN_BLEND_M, 0.5 * np.minimum(lengths[:-1], lengths[1:]))
    knots = np.column_stack([arc[1:-1] - blend, arc[1:-1] + blend]).ravel()
    angles = np.column_stack([values[:-1], values[1:]]).ravel()
    return np.interp(along, knots, angles)
