"""What a knife's edge cuts: the board segments its blade covers, and their length in the food.

The blade is a straight horizontal edge at the tip's height in the vertical plane of the tool x
axis, reaching `blade_length` from the tip back against the direction of travel. While the tip is
below the object's top the whole edge is, so the cut is the union of the edge's positions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from keymps.robot.safety_geometry import row_norms
from keymps.sorted_values import distinct

SWEEP_STEP_M = 0.0005
"""The blade's position is taken each time its tip or far end has moved this far."""
NO_TRAVEL_M = 0.001
"""A work piece moving the tip less than this sideways (a plunge) has no direction of travel:
its blade lies along the tool's -x axis."""
LENGTH_BIN_M = 0.0005
"""Resolution of the measured cut lengths."""
FOOTPRINT_CELL_M = 0.00025
"""Grid cell of the rasterised footprint used to clip the measured cuts."""
COARSE_SAMPLES = 16
"""Every this many blade samples one is tested against the footprint; the ones between only
near its edge."""


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
    return edge_samples(tip_xyz, backwards, blade_length)[1]


def edge_samples(
    tip_xyz: np.ndarray, backwards: np.ndarray | None, blade_length: float
) -> tuple[np.ndarray, np.ndarray]:
    """edge_segments with, per segment, the sample it was taken at (a step of the tip's path:
    the step's first sample)."""
    tip = np.asarray(tip_xyz, dtype=float)[:, :2]
    if blade_length <= 0 or backwards is None:
        return np.arange(len(tip) - 1), np.stack([tip[:-1], tip[1:]], axis=1)
    far = tip + blade_length * backwards
    keep = _every(np.asarray(tip_xyz, dtype=float), far, SWEEP_STEP_M)
    return keep, np.stack([tip[keep], far[keep]], axis=1)


def _every(tip: np.ndarray, far: np.ndarray, step: float) -> np.ndarray:
    """Indices of the samples where the tip or the far end has moved `step` since the last one,
    plus the first and the last."""
    moved = np.maximum(row_norms(tip[1:] - tip[:-1]), row_norms(far[1:] - far[:-1]))
    distance = np.concatenate([[0.0], np.cumsum(moved)])
    bins = np.floor(distance / step)
    keep = np.flatnonzero(np.diff(bins, prepend=-1.0) > 0)  # ascending, the first included
    return keep if keep[-1] == len(tip) - 1 else np.append(keep, len(tip) - 1)


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
        self.ringed = np.pad(self.mask > 0, 1)
        """The mask with a ring of outside cells round it (what `cells` index)."""
        self._last_cell = np.array([cols, rows], dtype=float)
        self._inside_counts: np.ndarray | None = None

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """(n,) whether each point (n, 2) lies in a footprint cell."""
        xy = np.asarray(xy, dtype=float)
        return self.contains_xy(xy[:, 0], xy[:, 1])

    def contains_xy(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether each point (x, y) lies in a footprint cell (x and y: arrays of one shape)."""
        return self.inside(self.cells(y, 1), self.cells(x, 0))

    def inside(self, rows: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """Whether cells of the ringed mask are footprint cells."""
        flat = rows * self.ringed.shape[1]
        flat += columns
        return self.ringed.ravel()[flat]

    def cells(self, values: np.ndarray, axis: int) -> np.ndarray:
        """The cells of coordinates along `axis` (0: x, columns; 1: y, rows) in the ringed
        mask, those beyond it clipped onto its ring."""
        cells = np.subtract(values, self.origin[axis])
        cells /= FOOTPRINT_CELL_M
        np.floor(cells, out=cells)
        np.clip(cells, -1.0, self._last_cell[axis], out=cells)
        index = cells.astype(np.intp)
        index += 1
        return index

    def inside_cells(
        self, columns: tuple[np.ndarray, np.ndarray], rows: tuple[np.ndarray, np.ndarray]
    ) -> np.ndarray:
        """How many cells of each box of ringed-mask cells (first and last column, first and
        last row, all included) are inside: a summed-area table's four corners."""
        if self._inside_counts is None:
            import cv2

            self._inside_counts = cv2.integral(self.ringed.astype(np.uint8))
        table = self._inside_counts
        (left, right), (top, bottom) = columns, rows
        return (
            table[bottom + 1, right + 1] - table[top, right + 1] - table[bottom + 1, left]
        ) + table[top, left]


def _polygons(polygon: np.ndarray | list[np.ndarray]) -> list[np.ndarray]:
    return list(polygon) if isinstance(polygon, list) else [np.asarray(polygon)]


def covered_length(segments: np.ndarray, footprint: Footprint | None) -> float:
    """Metres of one cut's line the segments (k, 2, 2) cover, inside the footprint when given.

    Each segment is sampled at the same fractions (at most half a length bin apart); the samples
    inside the footprint are projected on their principal axis (the cut's line) and the length
    is the number of LENGTH_BIN_M bins they occupy. Consecutive samples of a segment are less
    than a bin apart along any axis, so the samples of a run of inside ones occupy every bin
    between the run's two ends: only each run's ends are projected, and the axis comes from the
    runs' sums of fractions and of their squares (a 2x2 scatter matrix, not an SVD)."""
    covered = covered_stretches(segments, footprint)
    return 0.0 if covered is None else covered.length_m


@dataclass(frozen=True)
class Stretches:
    """The stretches of a cut's line that a sweep covered: the line (a point and a unit axis,
    board metres) and the covered intervals along it."""

    origin: np.ndarray
    """(2,) a point of the line (the covered samples' mean)."""
    axis: np.ndarray
    """(2,) the line's unit direction (the samples' principal axis)."""
    bins: np.ndarray
    """(m, 2) int: the first and last LENGTH_BIN_M bin of each covered interval, ascending,
    bins counted along `axis` from `origin`."""
    run_segments: np.ndarray
    """Per run of covered samples, the segment it lies on."""
    run_bins: np.ndarray
    """(r, 2) int: per run, its first and last bin."""

    def of(self, segments: np.ndarray) -> Stretches | None:
        """The stretches only the segments marked in `segments` (a mask over them) cover, on
        the same line; None when they cover nothing."""
        mine = segments[self.run_segments]
        if not mine.any():
            return None
        low, high = self.run_bins[mine, 0], self.run_bins[mine, 1]
        return replace(self, bins=_union(low, high), run_segments=self.run_segments[mine],
                       run_bins=self.run_bins[mine])  # fmt: skip

    @property
    def length_m(self) -> float:
        return float((self.bins[:, 1] - self.bins[:, 0] + 1).sum() * LENGTH_BIN_M)

    def segments(self) -> np.ndarray:
        """(m, 2, 2) each covered interval as a segment of the line (board metres)."""
        ends = np.stack([self.bins[:, 0], self.bins[:, 1] + 1], axis=1) * LENGTH_BIN_M
        return self.origin + ends[:, :, None] * self.axis


def covered_stretches(segments: np.ndarray, footprint: Footprint | None) -> Stretches | None:
    """The stretches of one cut's line the segments (k, 2, 2) cover, inside the footprint when
    given (covered_length's intervals); None when they cover nothing."""
    if len(segments) == 0:
        return None
    starts = np.ascontiguousarray(segments[:, 0], dtype=float)
    steps = np.ascontiguousarray(segments[:, 1], dtype=float) - starts
    longest = float(np.sqrt((steps**2).sum(axis=1)).max())
    fractions = np.linspace(0.0, 1.0, max(2, math.ceil(2 * longest / LENGTH_BIN_M) + 1))
    if footprint is None:
        rows = np.arange(len(segments))
        first = np.zeros(len(segments), np.intp)
        last = np.full(len(segments), len(fractions) - 1)
    else:
        rows, first, last = _inside_runs(starts, steps, fractions, footprint)
    count = last - first + 1
    if count.sum() < 2:
        return None
    start, step = starts[rows], steps[rows]
    mean, axis = _principal_axis(start, step, fractions, first, last)
    ends = [(start + fractions[index, None] * step - mean) @ axis for index in (first, last)]
    low = np.floor(np.minimum(*ends) / LENGTH_BIN_M).astype(np.int64)
    high = np.floor(np.maximum(*ends) / LENGTH_BIN_M).astype(np.int64)
    return Stretches(mean, axis, _union(low, high), rows, np.stack([low, high], axis=1))


def _inside_runs(
    starts: np.ndarray, steps: np.ndarray, fractions: np.ndarray, footprint: Footprint
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs of consecutive samples start + fraction * step inside the footprint: each run's
    segment, first and last sample index (segment by segment, in order).

    Every COARSE_SAMPLES-th sample is tested. The samples between two tested ones are tested
    too only when the cells round them are not all of one kind (near the footprint's edge):
    runs begin and end only there, or at a segment's ends."""
    n = len(fractions)
    coarse = distinct(np.append(np.arange(0, n, COARSE_SAMPLES), n - 1))
    gaps = np.diff(coarse)
    cell_column = footprint.cells(starts[:, 0, None] + fractions[coarse] * steps[:, 0, None], 0)
    cell_row = footprint.cells(starts[:, 1, None] + fractions[coarse] * steps[:, 1, None], 1)
    inside = footprint.inside(cell_row, cell_column)
    # The samples between two tested ones lie in the box of their cells (grown by a cell for
    # rounding): when every cell of that box is of one kind, so are they.
    last = np.array(footprint.ringed.shape) - 1
    columns = _grown_box(cell_column[:, :-1], cell_column[:, 1:], last[1])
    rows = _grown_box(cell_row[:, :-1], cell_row[:, 1:], last[0])
    count = footprint.inside_cells(columns, rows)
    area = (columns[1] - columns[0] + 1) * (rows[1] - rows[0] + 1)
    settled = (count == 0) | (count == area)
    segment, gap = np.nonzero(~settled)
    # each unsettled gap's samples, its first to the one before the next tested one
    counts = gaps[gap]
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    row, sample = np.repeat(segment, counts), np.repeat(coarse[gap], counts) + offsets
    start, step, fraction = starts[row], steps[row], fractions[sample]
    tested = footprint.contains_xy(
        start[:, 0] + fraction * step[:, 0], start[:, 1] + fraction * step[:, 1]
    )
    # a change between a sample and the next: within a gap, or from its last to the next
    # tested sample
    following = np.append(tested[1:], False)
    gap_end = np.cumsum(counts) - 1
    following[gap_end] = inside[segment, gap + 1]
    change = following.astype(np.int8) - tested
    opened_row, opened_at = row[change == 1], sample[change == 1] + 1
    closed_row, closed_at = row[change == -1], sample[change == -1]
    # runs that begin at a segment's first sample or end at its last
    first_in, last_in = np.flatnonzero(inside[:, 0]), np.flatnonzero(inside[:, -1])
    opened_row = np.append(opened_row, first_in)
    opened_at = np.append(opened_at, np.zeros(len(first_in), np.intp))
    closed_row = np.append(closed_row, last_in)
    closed_at = np.append(closed_at, np.full(len(last_in), n - 1))
    opened = np.sort(opened_row * n + opened_at)  # in each segment runs open, close in turn
    closed = np.sort(closed_row * n + closed_at)
    return opened // n, opened % n, closed % n


def _grown_box(a: np.ndarray, b: np.ndarray, last: int) -> tuple[np.ndarray, np.ndarray]:
    """The cells from min(a, b) - 1 to max(a, b) + 1, within 0 .. last."""
    return np.maximum(np.minimum(a, b) - 1, 0), np.minimum(np.maximum(a, b) + 1, last)


def _principal_axis(
    start: np.ndarray, step: np.ndarray, fractions: np.ndarray, first: np.ndarray, last: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The mean and the unit principal axis of the samples start + f * step, f = fractions[i]
    for i in first..last, from sums over each run (about a reference point, for precision)."""
    cumulative = np.concatenate([[0.0], np.cumsum(fractions)])
    squares = np.concatenate([[0.0], np.cumsum(fractions**2)])
    count = (last - first + 1).astype(float)
    f1 = cumulative[last + 1] - cumulative[first]
    f2 = squares[last + 1] - squares[first]
    reference = (start + 0.5 * step).mean(axis=0)
    s = start - reference
    total = count.sum()
    mean = (count @ s + f1 @ step) / total
    # sum over samples of p p^T, p = s + f step: count s s^T + f1 (s step^T + step s^T) + f2 step step^T
    scatter = (
        np.einsum("k,ki,kj->ij", count, s, s)
        + np.einsum("k,ki,kj->ij", f1, s, step)
        + np.einsum("k,ki,kj->ij", f1, step, s)
        + np.einsum("k,ki,kj->ij", f2, step, step)
    ) - total * np.outer(mean, mean)
    (a, b), (_, c) = scatter
    largest = 0.5 * (a + c) + math.hypot(0.5 * (a - c), b)
    # the eigenvector of the largest eigenvalue, from the better-conditioned of the two rows
    axis = np.array([b, largest - a]) if largest - a >= largest - c else np.array([largest - c, b])
    norm = math.hypot(*axis)
    axis = axis / norm if norm > 0 else np.array([1.0, 0.0])
    return mean + reference, axis


def _union(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """(m, 2) the union of the integer intervals [low[i], high[i]] as disjoint intervals,
    ascending (touching ones joined: [1, 3] and [4, 6] are [1, 6])."""
    order = np.argsort(low, kind="stable")
    low, high = low[order], high[order]
    reach = np.maximum.accumulate(high)
    opens = np.concatenate([[True], low[1:] > reach[:-1] + 1])
    starts = np.flatnonzero(opens)
    ends = np.append(starts[1:], len(low)) - 1
    return np.stack([low[starts], reach[ends]], axis=1)
