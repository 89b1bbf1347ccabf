"""The paper's accuracy metric D (Sec. V-B, "Evaluation Method") and a few helpers around it.

D compares a generated motion with a ground-truth motion, both as 3D points in metres:

1. the ground truth is resampled to N points evenly along its arc length, piece by piece (each
   piece gets a share of the N points proportional to its length, at least one);
2. for each ground-truth point in order, the closest generated point not yet paired is found;
3. D is the mean of those N distances.

Only work pieces (the cuts or icing strokes) should be passed: travel moves are the caller's to
exclude. D ignores the order in which the generated points were executed, as the paper notes.

When there are fewer generated points than N, pairing restarts once every generated point is
paired (each may then be used again); pass densely sampled paths (keymps' work pieces are
sampled every millimetre) to avoid that.

The nearest-free search is numpy (it was scipy's cKDTree, whose import every `keymps eval`
process paid); the optimal assignment is scipy's compiled solver, loaded on its own
(keymps/eval/assignment.py). tests/eval/test_metric.py checks both against scipy's public API on
generated motions.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np

from keymps.eval.assignment import min_cost_assignment

DEFAULT_N = 100
"""Number of ground-truth points D is computed on."""

Points = np.ndarray | Sequence[np.ndarray]
"""An (n, 3) array of points, or a sequence of such arrays (pieces: cut 1, cut 2 ...)."""


def _as_pieces(points: Points, what: str) -> list[np.ndarray]:
    if isinstance(points, np.ndarray) and points.ndim == 2:
        pieces = [points]
    else:
        pieces = [np.asarray(p, dtype=float) for p in points]
    checked = []
    for index, piece in enumerate(pieces):
        arr = np.asarray(piece, dtype=float)
        if arr.ndim != 2 or arr.shape[1] not in (2, 3):
            raise ValueError(f"{what} piece {index}: expected shape (n, 3), got {arr.shape}")
        if len(arr) and not np.all(np.isfinite(arr)):
            raise ValueError(f"{what} piece {index}: contains NaN or infinite values")
        if len(arr):
            checked.append(arr)
    if not checked:
        raise ValueError(f"{what}: no points")
    dims = {p.shape[1] for p in checked}
    if len(dims) != 1:
        raise ValueError(f"{what}: pieces mix 2D and 3D points")
    return checked


def _piece_length(piece: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(piece, axis=0), axis=1).sum())


def _share_points(lengths: np.ndarray, n: int) -> np.ndarray:
    """How many of n points each piece gets: proportional to its length (largest remainders
    round up), at least one each."""
    count = len(lengths)
    if n < count:
        raise ValueError(f"n = {n} is fewer than the {count} ground-truth pieces")
    total = float(lengths.sum())
    ideal = n * lengths / total if total > 0 else np.full(count, n / count)
    shares = np.floor(ideal).astype(int)
    order = np.argsort(-(ideal - shares), kind="stable")
    shares[order[: n - shares.sum()]] += 1
    while (shares == 0).any():  # a very short piece still gets a point, from the largest share
        shares[int(np.argmax(shares))] -= 1
        shares[int(np.argmin(shares))] += 1
    return shares


def resample_along(piece: np.ndarray, count: int) -> np.ndarray:
    """`count` points evenly spaced along the polyline's arc length, both ends included."""
    if count <= 0:
        return np.zeros((0, piece.shape[1]))
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(piece, axis=0), axis=1))])
    if arc[-1] <= 0:
        return np.repeat(piece[:1], count, axis=0)
    targets = np.linspace(0.0, arc[-1], count) if count > 1 else np.array([arc[-1] / 2])
    return np.stack([np.interp(targets, arc, piece[:, d]) for d in range(piece.shape[1])], axis=1)


def resample_ground_truth(ground_truth: Points, n: int = DEFAULT_N) -> np.ndarray:
    """The N ground-truth points D is computed on, piece by piece in order."""
    pieces = _as_pieces(ground_truth, "ground truth")
    lengths = np.array([_piece_length(p) for p in pieces])
    shares = _share_points(lengths, n)
    return np.concatenate([resample_along(p, k) for p, k in zip(pieces, shares, strict=True)])


FIRST_NEIGHBOURS = 16
"""Nearest candidates listed per reference point up front; a full search only when they are
all paired."""
CACHE_BLOCK = 1 << 15
"""Distances computed at once (256 kB, reused: the arithmetic stays in the processor's cache
and no fresh memory is touched)."""


def _squared(difference: np.ndarray) -> np.ndarray:
    """Squared lengths along the last axis, summed coordinate by coordinate (as scipy does)."""
    total = difference[..., 0] * difference[..., 0]
    for axis in range(1, difference.shape[-1]):
        total += difference[..., axis] * difference[..., axis]
    return total


def _distance_blocks(points: np.ndarray, others: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
    """(first row, squared distances of a block of rows to every other point): the same sums as
    _squared, one coordinate at a time over contiguous columns, in one reused buffer (valid
    until the next block)."""
    columns = [np.ascontiguousarray(others[:, axis]) for axis in range(points.shape[1])]
    rows = max(1, CACHE_BLOCK // max(1, len(others)))
    buffer = np.empty((2, min(rows, len(points)), len(others)))
    for begin in range(0, len(points), rows):
        chunk = points[begin : begin + rows]
        block, part = buffer[0, : len(chunk)], buffer[1, : len(chunk)]
        np.subtract(chunk[:, 0, None], columns[0], out=block)
        np.multiply(block, block, out=block)
        for axis in range(1, points.shape[1]):
            np.subtract(chunk[:, axis, None], columns[axis], out=part)
            np.multiply(part, part, out=part)
            block += part
        yield begin, block


def _nearest_lists(
    reference: np.ndarray, candidates: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """Each reference point's k nearest candidates, nearest first (equally near ones by index),
    and their squared distances."""
    n, m = len(reference), len(candidates)
    indexes, distances = np.empty((n, k), dtype=np.intp), np.empty((n, k))
    for begin, block in _distance_blocks(reference, candidates):
        if k < m:
            near = np.argpartition(block, k - 1, axis=1)[:, :k]
        else:
            near = np.broadcast_to(np.arange(m), block.shape)
        near_d = np.take_along_axis(block, near, axis=1)
        order = np.lexsort((near, near_d), axis=1)
        indexes[begin : begin + len(block)] = np.take_along_axis(near, order, axis=1)
        distances[begin : begin + len(block)] = np.take_along_axis(near_d, order, axis=1)
    return indexes, distances


def _greedy_pairing(reference: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """For each reference point in order, the index of the closest candidate not yet paired
    (of equally close ones the lowest index).

    Each point's FIRST_NEIGHBOURS nearest are listed up front (distances of all pairs, in
    blocks); the first free one in the list is the answer when it is nearer than the list's
    last (an equally near candidate left out of the list could have a lower index). Otherwise
    the point searches all candidates (over _Boxes from BOX_SEARCH_CANDIDATES candidates on)."""
    return _greedy_from_lists(reference, candidates)[0]


def _greedy_from_lists(
    reference: np.ndarray, candidates: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """_greedy_pairing, and each point's smallest squared distance."""
    n, m = len(reference), len(candidates)
    k = min(m, FIRST_NEIGHBOURS)
    boxes = _Boxes(candidates) if m >= BOX_SEARCH_CANDIDATES else None
    if boxes is not None:
        indexes, distances = boxes.nearest_lists(reference, k)
    else:
        indexes, distances = _nearest_lists(reference, candidates, k)
    listed, limits = indexes.tolist(), distances[:, -1].tolist()
    near_d = distances.tolist()
    taken = bytearray(m)
    used = 0
    chosen = np.empty(n, dtype=np.intp)
    search: _FullSearch | None = None
    for i in range(n):
        if used == m:  # every candidate paired: start a new round
            taken = bytearray(m)
            used = 0
            if boxes is not None:
                boxes.free_all()
        for j, d in zip(listed[i], near_d[i], strict=True):
            if not taken[j]:
                if d < limits[i] or k == m:
                    break
                j = -1  # as near as the list's last: the whole set decides
                break
        else:
            j = -1
        if j < 0:
            if boxes is not None:
                j = boxes.nearest_free(reference[i])
            else:
                search = search or _FullSearch(candidates)
                j = search.nearest_free(reference[i], np.frombuffer(taken, dtype=bool))
        chosen[i] = j
        taken[j] = 1
        if boxes is not None:
            boxes.take(j)
        used += 1
    return chosen, distances[:, 0]


class _FullSearch:
    """The nearest free candidate of one point among all, in buffers reused from point to
    point (the same sums as _squared, over contiguous coordinate columns)."""

    def __init__(self, candidates: np.ndarray) -> None:
        self.columns = [np.ascontiguousarray(c) for c in candidates.T]
        self.total, self.part = np.empty(len(candidates)), np.empty(len(candidates))

    def nearest_free(self, point: np.ndarray, taken: np.ndarray) -> int:
        total, part = self.total, self.part
        np.subtract(self.columns[0], point[0], out=total)
        np.multiply(total, total, out=total)
        for axis in range(1, len(self.columns)):
            np.subtract(self.columns[axis], point[axis], out=part)
            np.multiply(part, part, out=part)
            total += part
        np.putmask(total, taken, np.inf)
        return int(total.argmin())  # (the first of equal minima: the lowest index)


CHUNK = 64
"""Candidates per box of the search over boxes (consecutive along a Z-order curve)."""
BOX_SEARCH_CANDIDATES = 1024
"""From this many candidates on, searches go over boxes."""


_SPREAD = {
    2: ((8, 0x00FF00FF), (4, 0x0F0F0F0F), (2, 0x33333333), (1, 0x55555555)),
    3: ((16, 0x030000FF), (8, 0x0300F00F), (4, 0x030C30C3), (2, 0x09249249)),
}
"""Shifts and masks moving bit b of a 10-bit number to bit b * dims (2 or 3 dimensions)."""


def _z_order(points: np.ndarray) -> np.ndarray:
    """A permutation of `points` along a Morton (Z-order) curve: consecutive points are near
    each other, so that runs of CHUNK consecutive points have small bounding boxes."""
    axes = np.ascontiguousarray(points.T)  # (numpy is slow on a last axis of 2 or 3)
    low = axes.min(axis=1)
    span = float((axes.max(axis=1) - low).max()) or 1.0
    bits = 10  # 1024 cubic cells along the longest side (a thin axis gets few)
    cells = ((axes - low[:, None]) / span * ((1 << bits) - 1)).astype(np.uint32)
    code = np.zeros(len(points), dtype=np.uint32)
    for axis in range(points.shape[1]):  # bit b of an axis goes to bit b * dims + axis
        spread = cells[axis]
        for shift, mask in _SPREAD[points.shape[1]]:
            spread = (spread | (spread << np.uint32(shift))) & np.uint32(mask)
        code |= spread << np.uint32(axis)
    return np.argsort(code)  # (any order of points in one cell is as good)


class _Boxes:
    """The candidates in boxes of CHUNK consecutive ones along a Z-order curve, for searches
    that skip the boxes too far away: rounding is monotonic, so no candidate is nearer than its
    box's bound. Keeps which candidates are paired (`take`).

    Coordinates are also kept axis by axis (numpy is several times slower on arrays whose
    last axis has only 2 or 3 entries); the sums are _squared's."""

    def __init__(self, candidates: np.ndarray) -> None:
        m, dims = candidates.shape
        self.order = _z_order(candidates)
        self.place = np.empty(m, dtype=np.intp)
        self.place[self.order] = np.arange(m)
        boxes = -(-m // CHUNK)
        self.size = np.minimum(CHUNK, m - np.arange(0, m, CHUNK))
        # each box's points padded to CHUNK with far away ones (never among the nearest)
        self.points = np.full((boxes * CHUNK, dims), np.inf)
        self.points[:m] = candidates[self.order]
        self.by_box = self.points.reshape(boxes, CHUNK, dims)
        self.axes = [
            np.ascontiguousarray(self.points[:, a]).reshape(boxes, CHUNK) for a in range(dims)
        ]
        last = self.size[-1]
        self.low = np.array([axis.min(axis=1) for axis in self.axes])
        self.high = np.array([axis.max(axis=1) for axis in self.axes])
        self.high[:, -1] = [axis[-1, :last].max() for axis in self.axes]
        self.index_by_box = np.append(self.order, np.full(boxes * CHUNK - m, m)).reshape(-1, CHUNK)
        self.free = self.size.copy()
        self.taken = np.zeros(boxes * CHUNK, dtype=bool)
        self.taken[m:] = True

    def bounds(self, points: np.ndarray) -> np.ndarray:
        """Squared distances of rows of points to each box, at most those to its members."""
        total = np.zeros((len(points), len(self.size)))
        for axis in range(points.shape[1]):
            at = points[:, axis, None]
            gap = np.maximum(self.low[axis] - at, 0.0)
            gap += np.maximum(at - self.high[axis], 0.0)
            gap *= gap
            total += gap
        return total

    def _distances(self, points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """Squared distances of each of the points to the CHUNK members of its box(es)."""
        shape = (slice(None),) + (None,) * (boxes.ndim)
        total = None
        for axis, coordinates in enumerate(self.axes):
            part = coordinates[boxes] - points[:, axis][shape]
            part *= part
            if total is None:
                total = part
            else:
                total += part
        assert total is not None
        return total

    def nearest_lists(self, reference: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """_nearest_lists: the k nearest among the candidates of each point's two nearest boxes
        bound its k-th nearest; only the boxes within that bound are searched, each for its k
        nearest first."""
        n, m = len(reference), len(self.order)
        indexes, distances = np.empty((n, k), dtype=np.intp), np.empty((n, k))
        rows = max(1, CACHE_BLOCK // len(self.size))
        for begin in range(0, n, rows):
            chunk = reference[begin : begin + rows]
            lower = self.bounds(chunk)
            two = np.argpartition(lower, 1, axis=1)[:, :2]  # (at least k + 1 candidates)
            near = self._distances(chunk, two).reshape(len(chunk), -1)
            bound = np.partition(near, k - 1, axis=1)[:, k - 1 : k]
            at, boxes = np.nonzero(lower <= bound)  # (grouped by point)
            block = self._distances(chunk[at], boxes)
            best = np.argpartition(block, k - 1, axis=1)[:, :k]
            count = np.bincount(at, minlength=len(chunk))
            slot = np.arange(len(at)) - np.repeat(np.cumsum(count) - count, count)
            by_slot_d = np.full((len(chunk), int(count.max()), k), np.inf)
            by_slot_i = np.full((len(chunk), int(count.max()), k), m)
            by_slot_d[at, slot] = np.take_along_axis(block, best, axis=1)
            by_slot_i[at, slot] = np.take_along_axis(self.index_by_box[boxes], best, axis=1)
            listed_d = by_slot_d.reshape(len(chunk), -1)
            listed_i = by_slot_i.reshape(len(chunk), -1)
            nearest = np.argpartition(listed_d, k - 1, axis=1)[:, :k]
            near_d = np.take_along_axis(listed_d, nearest, axis=1)
            near_i = np.take_along_axis(listed_i, nearest, axis=1)
            order = np.lexsort((near_i, near_d), axis=1)
            indexes[begin : begin + len(chunk)] = np.take_along_axis(near_i, order, axis=1)
            distances[begin : begin + len(chunk)] = np.take_along_axis(near_d, order, axis=1)
        return indexes, distances

    def take(self, index: int) -> None:
        place = self.place[index]
        self.taken[place] = True
        self.free[place // CHUNK] -= 1

    def free_all(self) -> None:
        self.taken[: len(self.order)] = False
        self.free[:] = self.size

    def nearest_free(self, point: np.ndarray) -> int:
        """The nearest candidate not taken (of equally near ones the lowest index): the box
        nearest first, then in order only those within its nearest free candidate (ordering
        all boxes would cost more than searching them) while they could hold a nearer one."""
        order, by_box, taken = self.index_by_box, self.by_box, self.taken
        bounds = self.bounds(point[None, :])[0]
        bounds[self.free == 0] = np.inf
        best, best_index = np.inf, len(self.order)
        box, later = int(bounds.argmin()), None
        while True:
            begin = box * CHUNK
            distances = _squared(by_box[box] - point)
            distances[taken[begin : begin + CHUNK]] = np.inf
            nearest = distances.min()
            if nearest <= best:
                index = int(order[box][distances == nearest].min())
                if nearest < best or index < best_index:
                    best, best_index = nearest, index
            if later is None:
                within = np.flatnonzero(bounds <= best)
                within = within[np.argsort(bounds[within], kind="stable")].tolist()
                later = iter([b for b in within if b != box])
            box = next(later, -1)
            if box < 0 or bounds[box] > best:
                return best_index


def _prepare(ground_truth: Points, generated: Points, n: int) -> tuple[np.ndarray, np.ndarray]:
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    reference = resample_ground_truth(ground_truth, n)
    candidates = np.concatenate(_as_pieces(generated, "generated"))
    # A canonical order makes ties between equally near points break the same way whatever
    # the order the generated motion came in: D is then exactly order-insensitive.
    candidates = candidates[_lexicographic_order(candidates)]
    if candidates.shape[1] != reference.shape[1]:
        raise ValueError(
            f"ground truth has {reference.shape[1]}D points, generated has {candidates.shape[1]}D"
        )
    return reference, candidates


def _lexicographic_order(points: np.ndarray) -> np.ndarray:
    """An order of the points by x, then y, then z (np.lexsort's but for the order among equal
    points): sorted by x, and only the runs of equal x sorted again by all three."""
    xs = np.ascontiguousarray(points[:, 0])
    order = np.argsort(xs)
    xs = xs[order]
    same = xs[1:] == xs[:-1]
    if not same.any():
        return order
    tied = np.zeros(len(xs), dtype=bool)
    tied[1:] |= same
    tied[:-1] |= same
    at = np.flatnonzero(tied)
    run = np.cumsum(np.append(True, ~same))[at]  # (the runs stay in place, in order)
    keys = [points[order[at], axis] for axis in range(points.shape[1] - 1, 0, -1)]
    order[at] = order[at][np.lexsort([*keys, run])]
    return order


def pair_distances(ground_truth: Points, generated: Points, n: int = DEFAULT_N) -> np.ndarray:
    """The N distances d_i of D (metres), in ground-truth order."""
    reference, candidates = _prepare(ground_truth, generated, n)
    chosen = _greedy_pairing(reference, candidates)
    return np.asarray(np.linalg.norm(reference - candidates[chosen], axis=1))


def metric_d(ground_truth: Points, generated: Points, n: int = DEFAULT_N) -> float:
    """The paper's D in metres: mean distance from N ground-truth points to their greedily paired
    closest unpaired generated points. Arrays of shape (N, 3) and (M, 3), or lists of pieces."""
    return float(pair_distances(ground_truth, generated, n).mean())


def metric_d_optimal(ground_truth: Points, generated: Points, n: int = DEFAULT_N) -> float:
    """D with the pairing that minimizes the total distance (Hungarian assignment) instead of the
    paper's greedy, order-dependent pairing: a lower bound of D, for comparison."""
    reference, candidates = _prepare(ground_truth, generated, n)
    return _optimal_mean(reference, candidates, None)


def metric_d_both(
    ground_truth: Points, generated: Points, n: int = DEFAULT_N
) -> tuple[float, float]:
    """(metric_d, metric_d_optimal) of the same motion, its nearest candidates listed once."""
    reference, candidates = _prepare(ground_truth, generated, n)
    lengths, nearest = _greedy_lengths(reference, candidates)
    return float(lengths.mean()), _optimal_mean(reference, candidates, (lengths, nearest))


PRUNE_FROM = 1 << 21
"""From this many reference-candidate pairs on (a 16 MB cost matrix), the candidates no optimal
pairing can use are left out before the assignment."""


def _greedy_lengths(reference: np.ndarray, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The greedy pairing's distances, and each reference point's smallest squared distance."""
    greedy, nearest = _greedy_from_lists(reference, candidates)
    return np.linalg.norm(reference - candidates[greedy], axis=1), nearest


def _optimal_mean(
    reference: np.ndarray,
    candidates: np.ndarray,
    greedy: tuple[np.ndarray, np.ndarray] | None,
) -> float:
    """The mean distance of the optimal assignment (`greedy`: _greedy_lengths, when known)."""
    if len(reference) * len(candidates) >= PRUNE_FROM:
        lengths, nearest = greedy if greedy else _greedy_lengths(reference, candidates)
        candidates = candidates[_usable(reference, candidates, lengths, nearest)]
    # Fewer candidates than reference points: each may serve ceil(n / m) of them, as in the
    # greedy pairing's rounds (whose total is then still that of a feasible assignment).
    rounds = -(-len(reference) // len(candidates))
    columns = np.tile(candidates, (rounds, 1)) if rounds > 1 else candidates
    cost = np.empty((len(reference), len(columns)))
    for begin, block in _distance_blocks(reference, columns):  # (no (n, m, 3) differences)
        np.sqrt(block, out=cost[begin : begin + len(block)])
    chosen = min_cost_assignment(cost)
    return float(cost[np.arange(len(reference)), chosen].mean())


def _usable(
    reference: np.ndarray, candidates: np.ndarray, lengths: np.ndarray, nearest: np.ndarray
) -> np.ndarray:
    """Which candidates an optimal assignment may use, from the greedy pairing's distances.

    Any assignment costs at least the sum of the row minima: a pair costing more than its row's
    minimum plus (greedy total - that sum) is in no optimal assignment (with a margin for
    rounding)."""
    lowest = np.sqrt(nearest)
    slack = max(0.0, float(lengths.sum()) - float(lowest.sum()))
    limits = (lowest + slack * (1 + 1e-9) + 1e-12)[:, None]
    usable = np.zeros(len(candidates), dtype=bool)
    for begin, block in _distance_blocks(reference, candidates):
        np.sqrt(block, out=block)
        usable |= (block <= limits[begin : begin + len(block)]).any(axis=0)
    return usable
