"""Distances the safety check measures: points to a polyline (the planned path) and points
outside a polygon (the object's footprint). The simulator measures with the same functions."""

from __future__ import annotations

from typing import Any

import numpy as np

from keymps.sorted_values import distinct


def row_norms(vectors: np.ndarray) -> np.ndarray:
    """(n,) Euclidean norms of (n, k) vectors: np.linalg.norm(vectors, axis=1) summed in the
    same order (the same values), without its temporaries (about ten times faster)."""
    vectors = np.asarray(vectors, dtype=float)
    squares = vectors[:, 0] * vectors[:, 0]
    for axis in range(1, vectors.shape[1]):
        squares += vectors[:, axis] * vectors[:, axis]
    return np.sqrt(squares, out=squares)


def _segment_distances(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances of points (n, 3) to segments a[i]-b[i] given per point: (n, k, 3) each."""
    ab = b - a
    length2 = np.maximum((ab**2).sum(axis=-1), 1e-18)
    t = np.clip(((points[:, None, :] - a) * ab).sum(axis=-1) / length2, 0.0, 1.0)
    gap = points[:, None, :] - (a + t[..., None] * ab)
    return np.sqrt((gap**2).sum(axis=-1))


def _pair_distances(
    points: np.ndarray,
    a: np.ndarray,
    ab: np.ndarray,
    length2: np.ndarray,
    point: np.ndarray,
    segment: np.ndarray,
) -> np.ndarray:
    """Distance of points[:, point[i]] to segment segment[i], from (3, n) point columns, (3, m)
    segment starts a and vectors ab = b - a and their squared lengths (at least 1e-18): the same
    arithmetic as `_segment_distances`, term by term (so the same value to the last bit)."""
    px, py, pz = points[0][point], points[1][point], points[2][point]
    ax, ay, az = a[0][segment], a[1][segment], a[2][segment]
    abx, aby, abz = ab[0][segment], ab[1][segment], ab[2][segment]
    t = (px - ax) * abx
    t += (py - ay) * aby
    t += (pz - az) * abz
    t /= length2[segment]
    np.clip(t, 0.0, 1.0, out=t)
    gx, gy, gz = px - (ax + t * abx), py - (ay + t * aby), pz - (az + t * abz)
    gx *= gx
    gx += gy * gy
    gx += gz * gz
    return np.sqrt(gx, out=gx)


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


def distance_to_polyline(
    points: np.ndarray, polyline: np.ndarray, within: float | None = None
) -> np.ndarray:
    """Exact distance of each point (n, 3) to a polyline (m, 3). `within`: a bound known on
    every distance (the grid pass then answers for every point)."""
    points = np.asarray(points, dtype=float)
    polyline = np.asarray(polyline, dtype=float)
    if len(polyline) == 1 or len(points) == 0:
        return np.linalg.norm(points - polyline[0], axis=1)
    segments = len(polyline) - 1
    if segments <= 2 * BLOCK_SEGMENTS or segments * len(points) <= 50_000:
        return _brute_force(points, polyline)
    a, b = polyline[:-1], polyline[1:]
    smallest = 0.0 if within is None else 8 * within * (1 + 1e-9) + 1e-12
    zeros = np.zeros(len(points), np.intp)
    out, near = _near(points, zeros, a, b, np.zeros(len(a), np.intp), smallest)
    if not near.all():
        out[~near] = _pruned(points[~near], polyline)
    return out


def distance_to_polylines(
    points: np.ndarray, which: np.ndarray, polylines: list[np.ndarray]
) -> np.ndarray:
    """Exact distance of each point (n, 3) to its own polyline, polylines[which[i]]: the same
    values as `distance_to_polyline` per polyline, with one grid pass for all of them."""
    points = np.asarray(points, dtype=float)
    which = np.asarray(which, dtype=np.intp)
    polylines = [np.asarray(p, dtype=float).reshape(-1, 3) for p in polylines]
    sizes = np.array([len(p) for p in polylines])
    out = np.zeros(len(points))
    near = np.zeros(len(points), dtype=bool)
    lines = np.flatnonzero(sizes >= 2)
    if len(lines) and len(points):
        vertices = np.concatenate([polylines[i] for i in lines])
        ends = np.cumsum(sizes[lines])
        keep = np.ones(len(vertices) - 1, dtype=bool)
        keep[ends[:-1] - 1] = False  # no segment from one polyline's end to the next's start
        a, b = vertices[:-1][keep], vertices[1:][keep]
        group_of_line = np.full(len(polylines), -1, np.intp)
        group_of_line[lines] = np.arange(len(lines))
        groups = group_of_line[which]
        mine = groups >= 0
        segment_group = np.repeat(np.arange(len(lines)), sizes[lines] - 1)
        if mine.all():  # every point has a line (as always for a trajectory): no copies
            out, near = _near(points, groups, a, b, segment_group)
        else:
            found, found_near = _near(points[mine], groups[mine], a, b, segment_group)
            out[mine], near[mine] = found, found_near
    if near.all():
        return out
    for line in distinct(which[~near]):
        rest = np.flatnonzero((which == line) & ~near)
        out[rest] = distance_to_polyline(points[rest], polylines[line])
    return out


PAIR_CHUNK = 8192
"""(Point, segment) pairs measured at a time."""
GRID_ENTRIES_PER_POINT = 8
"""The grid pass is skipped when it would register more segment-cell pairs than this per point
plus 100,000 (long segments against a fine grid: the pruned search is cheaper then)."""


def _near(
    points: np.ndarray,
    point_group: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    segment_group: np.ndarray,
    smallest_cell: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact distances of the points near their group's segments a[i]-b[i] (groups numbered
    0, 1, ... in order, each with at least one segment), and which points those are. With
    `smallest_cell` 8 d, every point within d of its group's segments is near.

    Each group has a uniform grid (cell size h), and every segment is registered in the cells
    its box, grown by h/4 on every side, overlaps. A point within h/8 of a segment lies inside
    that grown box with a margin of h/8, far more than rounding, so the segment is registered
    in the point's cell: when the nearest segment of the point's cell is within h/8, it is the
    nearest of all. The others are left to the pruned search."""
    out = np.zeros(len(points))
    near = np.zeros(len(points), dtype=bool)
    if len(points) == 0:
        return out, near
    grid = _grid(a, b, segment_group, smallest_cell)
    if grid.total > GRID_ENTRIES_PER_POINT * len(points) + 100_000:
        return out, near
    first, found = grid.cell_segments(points, point_group)
    has = np.flatnonzero(found)
    if len(has) == 0:
        return out, near
    counts = found[has]
    starts = np.cumsum(counts) - counts
    # every (point, segment of its cell) pair, grouped by point
    pair_point = np.repeat(has, counts)
    offsets = np.arange(len(pair_point)) - np.repeat(starts, counts)
    pair_segment = grid.entries()[0][np.repeat(first[has], counts) + offsets]
    best = np.minimum.reduceat(grid.pair_distances(points, pair_point, pair_segment), starts)
    out[has] = best
    near[has] = best <= grid.margin[point_group[has]] / 2
    return out, near


class _Grid:
    """The uniform grids of `_near` for one set of segments: built once, kept for the next
    points measured against the same segments (the simulator's after the safety check's)."""

    def __init__(self, a: np.ndarray, b: np.ndarray, segment_group: np.ndarray, smallest: float):
        self.a, self.b, self.segment_group = a, b, segment_group
        self.groups = groups = int(segment_group[-1]) + 1
        self.first_segment = first_segment = np.flatnonzero(np.diff(segment_group, prepend=-1))
        lengths = np.sqrt(((b - a) ** 2).sum(axis=1))
        low_corner = np.minimum.reduceat(np.minimum(a, b), first_segment, axis=0)
        high_corner = np.maximum.reduceat(np.maximum(a, b), first_segment, axis=0)
        extent = (high_corner - low_corner).max(axis=1)
        mean = np.add.reduceat(lengths, first_segment) / np.diff(first_segment, append=len(a))
        longest = np.maximum.reduceat(lengths, first_segment)
        # About two cells per segment: fewer segments per cell, few cells per segment.
        cell = np.maximum.reduce([mean, longest / 4, extent / 1000, np.full(groups, 1e-9)]) / 2
        self.cell = cell = np.maximum(cell, smallest)
        self.margin = margin = cell / 4
        self.origin = origin = low_corner - 2 * cell[:, None]
        seg_cell, seg_origin = cell[segment_group, None], origin[segment_group]
        low = np.floor((np.minimum(a, b) - margin[segment_group, None] - seg_origin) / seg_cell)
        high = np.floor((np.maximum(a, b) + margin[segment_group, None] - seg_origin) / seg_cell)
        self.low, high = low.astype(np.int64), high.astype(np.int64)
        self.shape = np.maximum.reduceat(high, first_segment, axis=0) + 1
        self.offset = np.concatenate([[0], np.cumsum(self.shape.prod(axis=1))[:-1]])
        self.counts = high - self.low + 1
        self.per_segment = self.counts.prod(axis=1)
        self.total = int(self.per_segment.sum())
        self.a_columns = np.ascontiguousarray(a.T)
        self.ab = np.ascontiguousarray((b - a).T)
        ab = self.ab
        self.length2 = np.maximum(ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2], 1e-18)
        self._entries: tuple[np.ndarray, ...] | None = None

    def entries(self) -> tuple[np.ndarray, ...]:
        """Every (segment, cell) registration sorted by cell: the segments, and per occupied
        cell where its segments start, its key and how many."""
        if self._entries is None:
            total, per_segment, counts, low = self.total, self.per_segment, self.counts, self.low
            # Every (segment, cell) pair: the cells of each segment's box counted in mixed radix.
            segment = np.repeat(np.arange(len(self.a)), per_segment)
            local = np.arange(total) - np.repeat(np.cumsum(per_segment) - per_segment, per_segment)
            yz = counts[segment, 1] * counts[segment, 2]
            cells = low[segment] + np.column_stack(
                [local // yz, (local % yz) // counts[segment, 2], local % counts[segment, 2]]
            )
            group = self.segment_group[segment]
            keys = _keys(cells, self.shape[group], self.offset[group])
            order = np.argsort(keys, kind="stable")
            keys, segment = keys[order], segment[order]
            cell_starts = np.flatnonzero(np.diff(keys, prepend=keys[0] - 1))
            self._entries = (
                segment,
                cell_starts,
                keys[cell_starts],
                np.diff(cell_starts, append=len(keys)),
            )
        return self._entries

    def cell_segments(
        self, points: np.ndarray, point_group: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """For each point (n, 3) of group point_group (n,), where the segments registered in
        its cell start in `entries()`'s segments and how many there are (0 outside its
        group's grid or in an empty cell): (n,) each."""
        _, cell_starts, cell_keys, cell_counts = self.entries()
        per_point = _per_point(point_group, self.groups)
        point_shape = per_point(self.shape)
        at = points - per_point(self.origin)
        at /= per_point(self.cell)[:, None]
        at = np.floor(at, out=at).astype(np.int64)
        ok = (at >= 0) & (at < point_shape)
        inside = ok[:, 0] & ok[:, 1] & ok[:, 2]  # faster than .all(axis=1) over three
        at_key = _keys(at, point_shape, per_point(self.offset))
        # Consecutive samples of a path mostly share a cell: one search per run of equal keys.
        run_start = np.flatnonzero(np.diff(at_key, prepend=at_key[0] - 1))
        found_at = np.searchsorted(cell_keys, at_key[run_start])
        where = np.minimum(
            np.repeat(found_at, np.diff(run_start, append=len(at_key))), len(cell_keys) - 1
        )
        hit = inside & (cell_keys[where] == at_key)
        return cell_starts[where], np.where(hit, cell_counts[where], 0)

    def pair_distances(
        self, points: np.ndarray, pair_point: np.ndarray, pair_segment: np.ndarray
    ) -> np.ndarray:
        """(pairs,) distance of points[pair_point[i]] (points (n, 3)) to the segment
        pair_segment[i]."""
        columns = np.ascontiguousarray(points.T)
        distances = np.empty(len(pair_point))
        for start in range(0, len(pair_point), PAIR_CHUNK):  # temporaries that stay in cache
            chunk = slice(start, start + PAIR_CHUNK)
            distances[chunk] = _pair_distances(
                columns,
                self.a_columns,
                self.ab,
                self.length2,
                pair_point[chunk],
                pair_segment[chunk],
            )
        return distances


_GRIDS: dict[bytes, _Grid] = {}
"""The last grids built, by a digest of their segments (a few: the check's and the sim's)."""


def _grid(a: np.ndarray, b: np.ndarray, segment_group: np.ndarray, smallest: float) -> _Grid:
    """The grids of these segments, built or as built before for the very same ones."""
    import hashlib

    digest = hashlib.sha1(usedforsecurity=False)
    for array in (a, b):
        digest.update(np.ascontiguousarray(array, dtype=float).reshape(-1).view(np.uint8).data)
    digest.update(
        np.ascontiguousarray(segment_group, dtype=np.int64).reshape(-1).view(np.uint8).data
    )
    digest.update(repr((np.shape(a), np.shape(b), float(smallest))).encode())
    key = digest.digest()
    grid = _GRIDS.get(key)
    if grid is None:  # copies: a caller may change its arrays afterwards
        a, b = np.array(a, dtype=float), np.array(b, dtype=float)
        grid = _Grid(a, b, np.array(segment_group, dtype=np.intp), smallest)
        if len(_GRIDS) >= 4:
            _GRIDS.pop(next(iter(_GRIDS)))
        _GRIDS[key] = grid
    return grid


def _per_point(groups: np.ndarray, count: int) -> Any:
    """A function giving each point its group's row of a per-group table: by repeating the
    rows when the points come group by group (as a path's samples do), else by indexing."""
    if len(groups) and bool((groups[1:] >= groups[:-1]).all()):
        repeats = np.bincount(groups, minlength=count)
        return lambda table: np.repeat(table, repeats, axis=0)
    return lambda table: table[groups]


def _keys(cells: np.ndarray, shape: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """One integer per (group, cell): the cell's row-major index in its group's grid."""
    return offset + (cells[:, 0] * shape[:, 1] + cells[:, 1]) * shape[:, 2] + cells[:, 2]


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
        away = lifted[outside]
        out[outside] = distance_to_polyline(away, flat, _near_bound(away[:, :2], closed))
    return out


def _near_bound(points: np.ndarray, polygon: np.ndarray) -> float | None:
    """A bound on the points' distances to the polygon (the farthest point's distance to the
    nearest of 64 of the corners) when it is small beside the polygon (the grid pass then
    answers for every point with few segments per cell), else None."""
    low, high = polygon.min(axis=0), polygon.max(axis=0)
    small = float((high - low).max()) / 16
    # no corner is nearer than the polygon's box: one point that far from the box decides
    off_box = np.maximum(np.maximum(low - points, points - high), 0.0)
    if float((off_box * off_box).sum(axis=1).max()) > small * small:
        return None
    corners = polygon[:: max(1, len(polygon) // 64)]
    bound = 0.0
    for start in range(0, len(points), 1024):
        gaps = points[start : start + 1024, None, :] - corners[None]
        bound = max(bound, float(np.sqrt((gaps**2).sum(axis=2)).min(axis=1).max()))
        if bound > small:  # (the rest cannot make it small again)
            return None
    return bound


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
