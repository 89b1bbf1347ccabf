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
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

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
"""Nearest neighbours fetched per ground-truth point up front; more only when all are taken."""


def _greedy_pairing(reference: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """For each reference point in order, the index of the closest candidate not yet paired."""
    from scipy.spatial import cKDTree

    n, m = len(reference), len(candidates)
    tree = cKDTree(candidates)
    k = min(m, FIRST_NEIGHBOURS)
    _, neighbours = tree.query(reference, k=k)
    neighbours = np.asarray(neighbours).reshape(n, k)
    taken = np.zeros(m, dtype=bool)
    used = 0
    chosen = np.empty(n, dtype=int)
    for i in range(n):
        if used == m:  # every candidate paired: start a new round
            taken[:] = False
            used = 0
        row = neighbours[i]
        free = ~taken[row]
        wider = k
        while not free.any():
            # Fewer than used + 1 candidates are taken, so the used + 1 nearest hold a free one:
            # widening the search (doubling) always ends.
            wider = min(2 * wider, used + 1, m)
            _, found = tree.query(reference[i], k=wider)
            row = np.atleast_1d(found)
            free = ~taken[row]
        j = int(row[np.argmax(free)])  # the nearest free one
        chosen[i] = j
        taken[j] = True
        used += 1
    return chosen


def _prepare(ground_truth: Points, generated: Points, n: int) -> tuple[np.ndarray, np.ndarray]:
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    reference = resample_ground_truth(ground_truth, n)
    candidates = np.concatenate(_as_pieces(generated, "generated"))
    # A canonical order makes ties between equally near points break the same way whatever
    # the order the generated motion came in: D is then exactly order-insensitive.
    candidates = candidates[np.lexsort(candidates.T[::-1])]
    if candidates.shape[1] != reference.shape[1]:
        raise ValueError(
            f"ground truth has {reference.shape[1]}D points, generated has {candidates.shape[1]}D"
        )
    return reference, candidates


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
    from scipy.optimize import linear_sum_assignment
    from scipy.spatial.distance import cdist

    reference, candidates = _prepare(ground_truth, generated, n)
    if len(candidates) < len(reference):  # the same reuse rule as the greedy pairing
        rounds = -(-len(reference) // len(candidates))
        candidates = np.tile(candidates, (rounds, 1))
    cost = cdist(reference, candidates)
    rows, cols = linear_sum_assignment(cost)
    return float(cost[rows, cols].mean())
