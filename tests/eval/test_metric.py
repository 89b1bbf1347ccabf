"""The paper's metric D: its definition on hand-checked cases and its properties (hypothesis)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.budget import Budget
from hypothesis import given, settings
from hypothesis import strategies as st

from keymps.eval.metric import (
    metric_d,
    metric_d_optimal,
    pair_distances,
    resample_along,
    resample_ground_truth,
)


def _cut(x: float, length: float = 0.1, n: int = 201) -> np.ndarray:
    """A straight vertical cut at x, sampled every 0.5 mm, at the board's surface."""
    y = np.linspace(0.0, length, n)
    return np.column_stack([np.full(n, x), y, np.zeros(n)])


def test_resampling_is_even_along_the_arc_and_shared_by_length() -> None:
    long, short = _cut(0.0, 0.3), _cut(0.1, 0.1)
    points = resample_ground_truth([long, short], n=100)
    assert len(points) == 100
    on_long = points[points[:, 0] == 0.0]
    assert len(on_long) == 75  # 3/4 of the length, 3/4 of the points
    steps = np.diff(on_long[:, 1])
    assert np.allclose(steps, steps[0])
    assert on_long[0, 1] == 0.0 and on_long[-1, 1] == pytest.approx(0.3)


def test_resample_along_a_polyline_with_a_corner() -> None:
    corner = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.1, 0.1, 0.0]])
    points = resample_along(corner, 5)
    assert np.allclose(points[:, :2], [[0, 0], [0.05, 0], [0.1, 0], [0.1, 0.05], [0.1, 0.1]])


def test_d_by_hand_greedy_order_matters() -> None:
    # Two ground-truth points, in order a then b; generated points p (near both) and q.
    # a takes p (0.1 away); b, whose closest is also p, must take q: D = (0.1 + 1.0) / 2.
    truth = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0]])
    generated = np.array([[0.1, 0.0, 0.0], [1.2, 0.0, 0.0]])
    distances = pair_distances(truth, generated, n=2)
    assert distances == pytest.approx([0.1, 1.0])
    assert metric_d(truth, generated, n=2) == pytest.approx(0.55)
    # the optimal assignment pays the same total here; it never pays more than greedy
    assert metric_d_optimal(truth, generated, n=2) <= metric_d(truth, generated, n=2) + 1e-12


def test_a_parallel_shift_costs_exactly_the_shift() -> None:
    truth = [_cut(0.05), _cut(0.10)]
    shifted = [p + [0.004, 0.0, 0.0] for p in truth]
    # the shifted copy is sampled every 0.5 mm along y: a point is at most 0.25 mm off in y
    bound = np.hypot(0.004, 0.00025)
    assert 0.004 - 1e-12 <= metric_d(truth, shifted) <= bound
    assert 0.004 - 1e-12 <= metric_d_optimal(truth, shifted) <= bound


def test_a_missing_cut_is_paid_for() -> None:
    truth = [_cut(0.05), _cut(0.10), _cut(0.15)]
    generated = [_cut(0.05), _cut(0.10)]
    assert metric_d(truth, generated) > 0.01  # the third cut's points pair 5 cm away or more


def test_travel_points_far_away_do_not_matter() -> None:
    truth = [_cut(0.05)]
    travel = np.column_stack([np.linspace(0, 0.3, 50), np.full(50, 0.2), np.full(50, 0.1)])
    exact = resample_ground_truth(truth)
    assert metric_d(truth, [exact, travel]) == pytest.approx(0.0, abs=1e-12)


def test_fewer_generated_points_than_n_are_reused_in_rounds() -> None:
    truth = _cut(0.0)
    one = np.array([[0.0, 0.05, 0.0]])
    assert metric_d(truth, one, n=10) == pytest.approx(
        np.mean(np.abs(np.linspace(0, 0.1, 10) - 0.05))
    )


@pytest.mark.parametrize(
    "truth, generated, message",
    [
        (np.zeros((0, 3)), np.zeros((3, 3)), "ground truth: no points"),
        (np.zeros((3, 3)), np.zeros((3, 2)), "2D"),
        (np.full((3, 3), np.nan), np.zeros((3, 3)), "NaN"),
        (np.zeros((3, 4)), np.zeros((3, 3)), "shape"),
    ],
)
def test_bad_input_is_a_clear_error(truth: np.ndarray, generated: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        metric_d(truth, generated)


def test_many_points_are_fast() -> None:
    rng = np.random.default_rng(0)
    truth = [_cut(x, n=2000) for x in np.linspace(0.02, 0.28, 15)]
    generated = rng.uniform(0, 0.3, size=(200_000, 3))
    budget = Budget()
    metric_d(truth, generated, n=1000)
    budget.check(2.0)


# --------------------------------------------------------------------------- properties

coordinate = st.floats(-0.3, 0.3, allow_nan=False, allow_infinity=False)
point = st.tuples(coordinate, coordinate, coordinate)
polyline = st.lists(point, min_size=2, max_size=12).map(lambda p: np.array(p, dtype=float))
pieces = st.lists(polyline, min_size=1, max_size=4)


def _densify(piece: np.ndarray, spacing: float = 0.0005) -> np.ndarray:
    """The same polyline sampled at most `spacing` apart and with at least 4 x 100 points."""
    length = float(np.linalg.norm(np.diff(piece, axis=0), axis=1).sum())
    return resample_along(piece, max(400, int(np.ceil(length / spacing)) + 1))


@settings(max_examples=60, deadline=None)
@given(pieces)
def test_d_of_a_path_with_itself_is_zero(path: list[np.ndarray]) -> None:
    """The ground truth's own N points, generated exactly, give D = 0."""
    sampled = resample_ground_truth(path, 100)
    assert metric_d(path, sampled) == pytest.approx(0.0, abs=1e-12)
    assert metric_d_optimal(path, sampled) == pytest.approx(0.0, abs=1e-12)


@settings(max_examples=40, deadline=None)
@given(pieces)
def test_d_of_a_densely_sampled_copy_is_below_the_sampling_step(path: list[np.ndarray]) -> None:
    dense = [_densify(p) for p in path]
    assert metric_d(path, dense) <= 0.0005


@settings(max_examples=40, deadline=None)
@given(
    pieces,
    st.tuples(coordinate, coordinate, coordinate).filter(lambda v: np.linalg.norm(v) > 1e-3),
    st.floats(1.5, 4.0),
)
def test_d_grows_with_a_shift(path: list[np.ndarray], offset: tuple, factor: float) -> None:
    dense = [_densify(p) for p in path]
    vector = np.array(offset)
    small = metric_d(path, [p + vector for p in dense])
    large = metric_d(path, [p + factor * vector for p in dense])
    assert small > 0
    assert large > small
    # a rigid shift of the whole path by v costs at most |v| (each point has its own copy)
    assert small <= np.linalg.norm(vector) + 0.0005


@settings(max_examples=40, deadline=None)
@given(pieces, st.integers(0, 2**32 - 1))
def test_d_ignores_the_order_of_the_generated_motion(path: list[np.ndarray], seed: int) -> None:
    generated = np.concatenate([_densify(p) for p in path]) + 0.003
    shuffled = generated[np.random.default_rng(seed).permutation(len(generated))]
    reversed_pieces = [p[::-1] for p in reversed([_densify(p) + 0.003 for p in path])]
    d = metric_d(path, generated)
    assert metric_d(path, shuffled) == pytest.approx(d, abs=1e-12)
    assert metric_d(path, reversed_pieces) == pytest.approx(d, abs=1e-12)


@settings(max_examples=40, deadline=None)
@given(pieces, pieces)
def test_optimal_assignment_never_exceeds_greedy(
    truth: list[np.ndarray], made: list[np.ndarray]
) -> None:
    generated = [resample_along(p, 30) for p in made]
    assert metric_d_optimal(truth, generated) <= metric_d(truth, generated) + 1e-12


# --------------------------------------------------------------------------- against scipy


def _scipy_greedy(reference: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """The pairing as keymps computed it with scipy's k-d tree, before the numpy search."""
    from scipy.spatial import cKDTree

    tree, taken, chosen = cKDTree(candidates), np.zeros(len(candidates), dtype=bool), []
    for point in reference:
        if taken.all():
            taken[:] = False
        k = min(len(candidates), int(taken.sum()) + 1)  # (the k nearest hold a free one)
        _, order = tree.query(point, k=k)
        j = int(np.atleast_1d(order)[np.argmax(~taken[np.atleast_1d(order)])])
        taken[j] = True
        chosen.append(j)
    return np.array(chosen)


def _generated_case(rng: np.random.Generator) -> tuple[list[np.ndarray], list[np.ndarray], int]:
    """A ground truth of straight or wavy cuts and a motion that follows it loosely: shifted,
    noisy, sawing across it, missing pieces or adding some, sparse or dense, 2D or 3D."""
    dims = int(rng.choice([2, 3]))
    truth, made = [], []
    for _ in range(int(rng.integers(1, 7))):
        start = rng.uniform(0, 0.3, dims)
        end = start + rng.normal(0, 0.08, dims)
        s = np.linspace(0, 1, int(rng.integers(2, 40)))[:, None]
        piece = start + s * (end - start)
        truth.append(piece)
        if rng.random() < 0.8:
            count = int(rng.integers(2, 600))
            t = np.linspace(0, 1, count)[:, None]
            wave = np.zeros((count, dims))
            wave[:, 0] = rng.uniform(0, 0.02) * np.sin(t[:, 0] * rng.uniform(1, 60))
            noise = rng.normal(0, rng.choice([0.0, 1e-4, 3e-3]), (count, dims))
            made.append(start + t * (end - start) + wave + noise + rng.normal(0, 0.005, dims))
    if not made or rng.random() < 0.2:
        made.append(rng.uniform(0, 0.3, (int(rng.integers(1, 300)), dims)))
    if rng.random() < 0.2:  # repeated points: equally near candidates
        made.append(made[0][: len(made[0]) // 2].copy())
    return truth, made, int(rng.choice([len(truth), 20, 100, 300]))


def _greedy_by_boxes(reference: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """_greedy_pairing by branch and bound over _Boxes for every point (no lists): exercises
    _Boxes.nearest_free on every point, not only where a list runs out."""
    from keymps.eval.metric import _Boxes

    n, m = len(reference), len(candidates)
    boxes = _Boxes(candidates)
    used = 0
    chosen = np.empty(n, dtype=np.intp)
    for i in range(n):
        if used == m:  # every candidate paired: start a new round
            boxes.free_all()
            used = 0
        chosen[i] = boxes.nearest_free(reference[i])
        boxes.take(int(chosen[i]))
        used += 1
    return chosen


@pytest.mark.parametrize("search", ["lists", "boxes"])
def test_the_numpy_greedy_pairing_is_scipys_on_generated_motions(search: str) -> None:
    from keymps.eval.metric import _greedy_pairing, _prepare

    pairing = _greedy_pairing if search == "lists" else _greedy_by_boxes
    rng = np.random.default_rng(20261202)
    for _ in range(150):
        truth, made, n = _generated_case(rng)
        reference, candidates = _prepare(truth, made, n)
        mine = pairing(reference, candidates)
        theirs = _scipy_greedy(reference, candidates)
        mine_d = np.linalg.norm(reference - candidates[mine], axis=1)
        theirs_d = np.linalg.norm(reference - candidates[theirs], axis=1)
        assert np.array_equal(mine_d, theirs_d)  # (equal distances: ties may pick other points)
        if search == "lists":
            assert metric_d(truth, made, n) == float(theirs_d.mean())


@pytest.mark.parametrize("prune_from", ["default", 0])
def test_the_optimal_d_is_scipys_on_generated_motions(
    prune_from: str | int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Candidates repeated in rounds, and (from PRUNE_FROM pairs on, here also from 0) those no
    optimal pairing can use left out: the pairs are those of scipy on all candidates."""
    from scipy.optimize import linear_sum_assignment
    from scipy.spatial.distance import cdist

    from keymps.eval import metric
    from keymps.eval.metric import _prepare, metric_d_both

    if prune_from != "default":
        monkeypatch.setattr(metric, "PRUNE_FROM", prune_from)

    rng = np.random.default_rng(20261203)
    for _ in range(50):
        truth, made, n = _generated_case(rng)
        reference, candidates = _prepare(truth, made, n)
        if len(candidates) < len(reference):
            candidates = np.tile(candidates, (-(-len(reference) // len(candidates)), 1))
        cost = cdist(reference, candidates)
        rows, columns = linear_sum_assignment(cost)
        expected = float(cost[rows, columns].mean())
        both = metric_d_both(truth, made, n)
        assert both == (metric_d(truth, made, n), metric_d_optimal(truth, made, n))
        assert both[1] == expected  # (the same pairs summed in the same order)


def test_the_box_search_lists_the_same_nearest_as_all_pairs_on_dense_motions() -> None:
    """From 1024 candidates on, the nearest lists and full searches go over boxes: the same
    distances as over all pairs, and the pairing is still scipy's."""
    from keymps.eval.metric import (
        FIRST_NEIGHBOURS,
        _Boxes,
        _greedy_pairing,
        _nearest_lists,
        _prepare,
    )

    rng = np.random.default_rng(20261205)
    for _ in range(40):
        truth, made, n = _generated_case(rng)
        dense = [np.repeat(p, int(rng.integers(2, 12)), axis=0) for p in made]
        dense = [p + rng.normal(0, rng.choice([0.0, 1e-4, 2e-3]), p.shape) for p in dense]
        dense.append(rng.uniform(0, 0.3, (1024, dense[0].shape[1])))  # (always boxes)
        reference, candidates = _prepare(truth, dense, n)
        _, expected = _nearest_lists(reference, candidates, FIRST_NEIGHBOURS)
        _, found = _Boxes(candidates).nearest_lists(reference, FIRST_NEIGHBOURS)
        assert np.array_equal(found, expected)
        mine = _greedy_pairing(reference, candidates)
        theirs = _scipy_greedy(reference, candidates)
        assert np.array_equal(
            np.linalg.norm(reference - candidates[mine], axis=1),
            np.linalg.norm(reference - candidates[theirs], axis=1),
        )


def test_the_canonical_order_is_lexsorts() -> None:
    from keymps.eval.metric import _lexicographic_order

    rng = np.random.default_rng(20261206)
    for case in range(300):
        points = rng.normal(size=(int(rng.integers(1, 2000)), int(rng.choice([2, 3]))))
        if case % 3 == 0:  # many equal coordinates, and equal points
            points = np.round(points, 1)
        if case % 4 == 0:
            points[: len(points) // 2, 0] = 0.0
        order = _lexicographic_order(points)
        assert np.array_equal(np.sort(order), np.arange(len(points)))
        assert np.array_equal(points[order], points[np.lexsort(points.T[::-1])])
