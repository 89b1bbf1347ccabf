"""Exact parametric keypoint designs: parallel and radial slices, grids, rings, spirals, stars ...

Every design is an array of shape (K, 2, 2): K pairs of (start, end) points. The functions work
in any planar units with x right and y down (the crop's convention); the offline planner feeds
them millimetres of the object's footprint and converts the result to crop pixels. Angles are
radians from +x towards +y, so -pi/2 points to the top of the image. A dot is a pair whose start
equals its end.
"""

from __future__ import annotations

import math

import numpy as np

from keymps.designs.outline import (
    TOP,
    Outline,
    PointLike,
    Values,
    as_pairs,
    chord,
    circle_polygon,
    direction,
    inset_polygon,
    line_hits,
    ray,
)

# --- cutting ---------------------------------------------------------------------------------


def offsets_by_count(length: float, parts: int) -> np.ndarray:
    """Cut offsets from the start that divide `length` into `parts` equal pieces."""
    if parts < 1:
        raise ValueError("parts must be at least 1")
    return np.arange(1, parts) * (length / parts)


def offsets_by_width(
    length: float, width: float, count: int | None = None, tolerance: float = 1e-6
) -> np.ndarray:
    """Cut offsets for slices of `width` from the start: `count` slices, or as many as fit.

    A cut that would fall on the far end (within `tolerance`) is dropped: that end is already free.
    """
    if width <= 0:
        raise ValueError("width must be positive")
    n = count if count is not None else int(math.floor(length / width + tolerance))
    offsets = np.arange(1, n + 1) * width
    return offsets[offsets < length - max(tolerance, 1e-9 * length)]


def parallel_cuts(
    outline: Outline, slicing_angle: float, offsets: Values, overshoot: float = 0.0
) -> np.ndarray:
    """Cuts across the object, perpendicular to `slicing_angle`, at `offsets` from its start.

    The start is the object's extreme point against the slicing direction. Each cut runs like
    a line of text: left to right, or top to bottom when it is closer to vertical.
    """
    low, _ = outline.extent(slicing_angle)
    axis = direction(slicing_angle)
    cut_angle = conventional_angle(slicing_angle + math.pi / 2)
    pairs = []
    for offset in offsets:
        point = outline.centre + (low + offset) * axis
        cut = chord(outline, point, cut_angle, overshoot)
        if cut is not None:
            pairs.append(cut)
    return as_pairs(pairs)


def conventional_angle(angle: float) -> float:
    """The direction of a line, chosen to point right, or down (+y) when closer to vertical."""
    dx, dy = math.cos(angle), math.sin(angle)
    flip = dy < 0 if abs(dy) > abs(dx) else dx < 0
    return angle + math.pi if flip else angle


def parallel_slices(
    outline: Outline,
    slicing_angle: float,
    *,
    parts: int | None = None,
    width: float | None = None,
    count: int | None = None,
    overshoot: float = 0.0,
) -> np.ndarray:
    """Equal parts by count (`parts`), or slices of `width` (`count` of them, or all that fit)."""
    low, high = outline.extent(slicing_angle)
    if parts is not None:
        offsets = offsets_by_count(high - low, parts)
    elif width is not None:
        offsets = offsets_by_width(high - low, width, count)
    else:
        raise ValueError("give parts or width")
    return parallel_cuts(outline, slicing_angle, offsets, overshoot)


def both_tips(
    outline: Outline, slicing_angle: float, inset: float, overshoot: float = 0.0
) -> np.ndarray:
    """Two cuts, `inset` in from each end of the object along `slicing_angle`."""
    low, high = outline.extent(slicing_angle)
    return parallel_cuts(outline, slicing_angle, [inset, high - low - inset], overshoot)


def radial_slices(
    outline: Outline,
    parts: int,
    start_angle: float = TOP,
    overshoot: float = 0.0,
    centre: np.ndarray | None = None,
) -> np.ndarray:
    """`parts` equal-angle wedges: full cuts through the centre when `parts` is even, else rays.

    The first cut passes through the point of the boundary at `start_angle` (the top); the next
    ones follow counter-clockwise as seen in the image. Full cuts start on the `start_angle`
    side (the first one runs from the top down); rays run from the edge in to the centre: a
    knife's edge trails its tip and ends flat on the board, so a ray cut outwards from the
    centre would end with the edge across the other side of the object.
    """
    if parts < 2:
        raise ValueError("radial slices need at least 2 parts")
    c = outline.centre if centre is None else np.asarray(centre, float)
    step = 2 * math.pi / parts  # y points down: counter-clockwise on screen is a falling angle
    if parts % 2 == 0:
        pairs = []
        for i in range(parts // 2):
            dirn = direction(start_angle + math.pi - i * step)
            hits = line_hits(outline, c, dirn)
            ahead, behind = hits[hits > 0], hits[hits < 0]
            back = float(behind.min()) if len(behind) else 0.0
            front = float(ahead.max()) if len(ahead) else 0.0
            pairs.append(np.array([c + (back - overshoot) * dirn, c + (front + overshoot) * dirn]))
        return as_pairs(pairs)
    rays = [ray(outline, c, start_angle - i * step, overshoot) for i in range(parts)]
    return as_pairs([cut[::-1] for cut in rays])


def grid_shape(parts: int, aspect: float = 1.0) -> tuple[int, int]:
    """(rows, cols) with rows * cols = parts whose cells are closest to square.

    `aspect` is the object's length along its axis divided by its width; columns run along the axis.
    """
    best: tuple[float, int, int] | None = None
    for rows in range(1, parts + 1):
        if parts % rows:
            continue
        cols = parts // rows
        cell = (aspect / cols) / (1.0 / rows)
        score = abs(math.log(cell))
        if (
            best is None
            or score < best[0] - 1e-9
            or (abs(score - best[0]) < 1e-9 and rows < best[1])
        ):
            best = (score, rows, cols)
    assert best is not None
    return best[1], best[2]


def grid_cuts(outline: Outline, rows: int, cols: int, overshoot: float = 0.0) -> np.ndarray:
    """Equal grid: cols - 1 cuts across the axis and rows - 1 cuts along it."""
    across = parallel_slices(outline, outline.axis_angle, parts=cols, overshoot=overshoot)
    along = parallel_slices(
        outline, outline.axis_angle + math.pi / 2, parts=rows, overshoot=overshoot
    )
    return np.concatenate([across, along], axis=0)


def grid_cell_centres(outline: Outline, rows: int, cols: int) -> np.ndarray:
    """(rows * cols, 2) centres of the cells of an equal grid over the object's extent."""
    u, v = outline.axis, direction(outline.axis_angle + math.pi / 2)
    u_low, u_high = outline.extent(outline.axis_angle)
    v_low, v_high = outline.extent(outline.axis_angle + math.pi / 2)
    centres = []
    for r in range(rows):
        for c in range(cols):
            a = u_low + (c + 0.5) * (u_high - u_low) / cols
            b = v_low + (r + 0.5) * (v_high - v_low) / rows
            centres.append(outline.centre + a * u + b * v)
    return np.array(centres)


# --- icing -----------------------------------------------------------------------------------


def dots(points: np.ndarray) -> np.ndarray:
    """One dot (start = end) at each point."""
    points = np.asarray(points, float).reshape(-1, 2)
    return np.stack([points, points], axis=1)


def ring_points(
    centre: PointLike, radius: float, count: int, start_angle: float = TOP
) -> np.ndarray:
    angles = start_angle + np.arange(count) * (2 * math.pi / count)
    return np.asarray(centre, float) + radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)


def ring_of_dots(
    centre: PointLike, radius: float, count: int, start_angle: float = TOP
) -> np.ndarray:
    """`count` dots evenly spaced on a circle."""
    return dots(ring_points(centre, radius, count, start_angle))


def inset_path(outline: Outline, inset: float) -> np.ndarray:
    """A closed path `inset` inside the boundary: a circle for round objects, else the measured
    boundary itself moved in (its rounded corners and uneven sides followed, so that every point
    of the path is `inset` from the nearest edge, as the outcome stage measures it)."""
    if outline.kind == "round":
        return circle_polygon(outline.centre, max(outline.radius - inset, 0.0), 360)
    if inset <= 0:
        return np.asarray(outline.polygon, float)
    return inset_polygon(outline.polygon, inset)


def thinned_path(path: np.ndarray, tolerance: float) -> np.ndarray:
    """A closed path with as few of its vertices as keep it within `tolerance` (its units) of
    itself (Douglas-Peucker): icing lines along it need fewer pairs."""
    import cv2

    points = np.asarray(path, np.float32).reshape(-1, 1, 2)  # what approxPolyDP takes
    return np.asarray(cv2.approxPolyDP(points, tolerance, True), float).reshape(-1, 2)


def points_along_closed_path(path: np.ndarray, count: int, start_angle: float = TOP) -> np.ndarray:
    """`count` points equally spaced by arc length on a closed path, starting nearest the top."""
    closed = np.vstack([path, path[:1]])
    steps = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    centre = path.mean(axis=0)
    headings = np.arctan2(path[:, 1] - centre[1], path[:, 0] - centre[0])
    first = int(np.argmin(np.abs(np.angle(np.exp(1j * (headings - start_angle))))))
    targets = (arc[first] + np.arange(count) * arc[-1] / count) % arc[-1]
    xs = np.interp(targets, arc, closed[:, 0])
    ys = np.interp(targets, arc, closed[:, 1])
    return np.stack([xs, ys], axis=1)


def dots_along_path(path: np.ndarray, count: int, start_angle: float = TOP) -> np.ndarray:
    """`count` dots equally spaced along a closed path (e.g. `inset_path`)."""
    return dots(points_along_closed_path(path, count, start_angle))


CHORD_SAMPLES = 2000
"""points_equally_apart walks a closed path resampled at this many points."""


def points_equally_apart(path: np.ndarray, count: int, start_angle: float = TOP) -> np.ndarray:
    """`count` points on a closed path, each the same straight-line distance from the next (and
    the last from the first), starting where points_along_closed_path does. Spaced by arc
    length instead, the two points either side of a square's corner are down to 0.71 of the
    spacing apart: icing dots there merge first. Where equal chords from that start keep the
    points closer than arc spacing does (three points on a long path), arc spacing.

    Args:
        path: (N, 2) a closed path's vertices in order (not repeated at the end).
        count: How many points (at least 1).
        start_angle: The first point's direction from the path's centre, radians.

    Returns:
        (count, 2) the points in the path's order.
    """
    by_arc = points_along_closed_path(path, count, start_angle)
    if count < 3:
        return by_arc
    ring = points_along_closed_path(path, CHORD_SAMPLES, start_angle)
    # equal chords fit from the closest arc-spaced neighbours' gap (or 0) up to the arc spacing
    low, high = 0.0, perimeter(ring) / count
    if _walk(ring, _closest(by_arc), count) is not None:
        low = _closest(by_arc)
    for _ in range(24):  # to a ten-millionth of the spacing at most
        chord = (low + high) / 2
        if _walk(ring, chord, count) is None:
            high = chord
        else:
            low = chord
    placed = _walk(ring, low, count)  # low always fits (a chord of 0 does): never None
    if placed is None or _closest(placed) < _closest(by_arc):
        return by_arc  # a few points on a long path: no equal chords from this start
    return placed


def gaps(points: np.ndarray) -> np.ndarray:
    """(n,) the distance from each of a closed chain of points (n, 2) to the next (the last's
    to the first)."""
    return np.asarray(np.linalg.norm(np.diff(np.vstack([points, points[:1]]), axis=0), axis=1))


def perimeter(path: np.ndarray) -> float:
    """The length of a closed path (n, 2)."""
    return float(gaps(path).sum())


def _closest(points: np.ndarray) -> float:
    """The shortest distance between neighbours on a closed chain of points (n, 2)."""
    return float(gaps(points).min())


def _walk(ring: np.ndarray, chord: float, count: int) -> np.ndarray | None:
    """Points along `ring` (M, 2) from its first, each `chord` from the one before, or None
    when `count` of them do not fit with the last at least `chord` from the first."""
    points, index = [ring[0]], 0
    window = int(3 * chord / max(perimeter(ring) / len(ring), 1e-12)) + 2
    for _ in range(count - 1):
        beyond = np.empty(0, int)
        for ahead in (ring[index + 1 : index + 1 + window], ring[index + 1 :]):  # near first
            beyond = np.flatnonzero(np.linalg.norm(ahead - points[-1], axis=1) >= chord)
            if len(beyond):
                break
        if not len(beyond):
            return None
        index += 1 + int(beyond[0])
        before = ring[index - 1]
        points.append(
            before + _fraction(points[-1], before, ring[index], chord) * (ring[index] - before)
        )
    if np.linalg.norm(points[-1] - points[0]) < chord:
        return None
    return np.array(points)


def _fraction(centre: np.ndarray, a: np.ndarray, b: np.ndarray, radius: float) -> float:
    """Where along a -> b (0-1) the segment leaves the circle about `centre` (a inside it)."""
    d, f = b - a, a - centre
    qa, qb, qc = float(d @ d), float(2 * f @ d), float(f @ f - radius**2)
    if qa < 1e-24:
        return 0.0
    return float(np.clip((-qb + math.sqrt(max(qb * qb - 4 * qa * qc, 0.0))) / (2 * qa), 0, 1))


def polyline(points: np.ndarray, closed: bool = False) -> np.ndarray:
    """Consecutive points joined into pairs: a chain of segments (closed: back to the first)."""
    points = np.asarray(points, float)
    if closed:
        points = np.vstack([points, points[:1]])
    return np.stack([points[:-1], points[1:]], axis=1)


def ring(
    centre: PointLike, radius: float, segments: int = 24, start_angle: float = TOP
) -> np.ndarray:
    """A circle as a closed chain of `segments` equal chords."""
    return polyline(ring_points(centre, radius, segments, start_angle), closed=True)


def concentric_rings(centre: PointLike, radii: Values, segments: int = 24) -> np.ndarray:
    return np.concatenate([ring(centre, r, segments) for r in radii], axis=0)


def spiral(
    centre: PointLike,
    inner_radius: float,
    outer_radius: float,
    turns: float,
    segments: int,
    start_angle: float = TOP,
) -> np.ndarray:
    """An Archimedean spiral from `inner_radius` to `outer_radius` as `segments` short segments."""
    s = np.linspace(0.0, 1.0, segments + 1)
    radius = inner_radius + (outer_radius - inner_radius) * s
    angle = start_angle + 2 * math.pi * turns * s
    points = np.asarray(centre, float) + radius[:, None] * np.stack(
        [np.cos(angle), np.sin(angle)], axis=1
    )
    return polyline(points)


def star(
    centre: PointLike,
    radius: float,
    points: int = 5,
    inner_ratio: float | None = None,
    start_angle: float = TOP,
) -> np.ndarray:
    """An n-pointed star.

    With `inner_ratio` None and n >= 5: the star polygon {n/2}, n straight lines joining every
    second tip (the pentagram for n = 5). Otherwise the outline through inner corners at
    `inner_ratio * radius`, 2n segments.
    """
    if points < 3:
        raise ValueError("a star needs at least 3 points")
    tips = ring_points(centre, radius, points, start_angle)
    if inner_ratio is None and points >= 5:
        return np.stack([tips, np.roll(tips, -2, axis=0)], axis=1)
    ratio = 0.4 if inner_ratio is None else inner_ratio
    inner = ring_points(centre, radius * ratio, points, start_angle + math.pi / points)
    corners = np.empty((2 * points, 2))
    corners[0::2], corners[1::2] = tips, inner
    return polyline(corners, closed=True)


SEVEN_SEGMENTS: dict[str, str] = {
    "0": "abcdef",
    "1": "bc",
    "2": "abged",
    "3": "abgcd",
    "4": "fgbc",
    "5": "afgcd",
    "6": "afgedc",
    "7": "abc",
    "8": "abcdefg",
    "9": "abcdfg",
    "-": "g",
    " ": "",
}
"""Lit segments per character: a top, b top-right, c bottom-right, d bottom, e bottom-left,
f top-left, g middle."""

DIGIT_WIDTH = 0.5
"""Character width as a fraction of its height."""
DIGIT_GAP = 0.3
"""Space between characters as a fraction of the height."""


def seven_segment_size(text: str, height: float) -> tuple[float, float]:
    """(width, height) of `text` drawn by `seven_segment`."""
    n = len(text)
    return n * DIGIT_WIDTH * height + max(n - 1, 0) * DIGIT_GAP * height, height


def seven_segment(text: str, centre: PointLike, height: float) -> np.ndarray:
    """`text` (digits, '-' and spaces) as seven-segment characters, one pair per lit segment."""
    unknown = sorted({ch for ch in text if ch not in SEVEN_SEGMENTS})
    if unknown:
        raise ValueError(f"no seven-segment form for {''.join(unknown)!r}")
    total_width, _ = seven_segment_size(text, height)
    w, h = DIGIT_WIDTH * height, height
    left = np.asarray(centre, float)[0] - total_width / 2
    top = np.asarray(centre, float)[1] - h / 2
    pairs = []
    for index, ch in enumerate(text):
        x0 = left + index * (w + DIGIT_GAP * height)
        corners = {
            "tl": (x0, top),
            "tr": (x0 + w, top),
            "ml": (x0, top + h / 2),
            "mr": (x0 + w, top + h / 2),
            "bl": (x0, top + h),
            "br": (x0 + w, top + h),
        }
        ends = {
            "a": ("tl", "tr"),
            "b": ("tr", "mr"),
            "c": ("mr", "br"),
            "d": ("bl", "br"),
            "e": ("ml", "bl"),
            "f": ("tl", "ml"),
            "g": ("ml", "mr"),
        }
        for segment in SEVEN_SEGMENTS[ch]:
            a, b = ends[segment]
            pairs.append(np.array([corners[a], corners[b]], dtype=float))
    return as_pairs(pairs)


def sector_centroid_distance(radius: float, parts: int) -> float:
    """Distance from the centre to the centroid of one of `parts` equal wedges of a disk."""
    half = math.pi / parts
    return 2 * radius * math.sin(half) / (3 * half)


def dot_per_radial_slice(
    outline: Outline, parts: int, start_angle: float = TOP, radius: float | None = None
) -> np.ndarray:
    """One dot at the middle (centroid) of each wedge of `radial_slices(outline, parts)`."""
    r = outline.radius if radius is None else radius
    distance = sector_centroid_distance(r, parts) if parts > 1 else 0.0
    step = 2 * math.pi / parts
    return ring_of_dots(outline.centre, distance, parts, start_angle + step / 2)


def dot_per_grid_cell(outline: Outline, rows: int, cols: int) -> np.ndarray:
    return dots(grid_cell_centres(outline, rows, cols))
