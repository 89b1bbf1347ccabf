"""keymps.motion.chains: icing pairs whose ends meet, grouped into the fewest continuous strokes."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from keymps.designs.patterns import seven_segment, spiral, star
from keymps.motion.chains import Chain, pipe_chains

LINE_WIDTH = 0.004
JOIN = 0.5 * LINE_WIDTH
TOP = 0.065


def lifted(pairs: np.ndarray, z: float = TOP) -> np.ndarray:
    """(K, 2, 2) board pairs at height z: (K, 2, 3)."""
    pairs = np.asarray(pairs, float)
    return np.concatenate([pairs, np.full(pairs.shape[:2] + (1,), z)], axis=2)


def chains_of(
    ends: np.ndarray, join: float = JOIN, objects: list[int] | None = None
) -> list[Chain]:
    return pipe_chains(ends, objects or [1] * len(ends), join)


def assert_valid(chains: list[Chain], ends: np.ndarray, join: float = JOIN) -> None:
    """Every pair piped exactly once; each chain's vertices are its pairs' ends, in order
    and direction, each moved by at most the join distance."""
    piped = [k for chain in chains for k in chain.pairs]
    assert sorted(piped) == list(range(len(ends)))
    for chain in chains:
        assert len(chain.reversed) == len(chain.pairs)
        assert chain.vertices.shape == (len(chain.pairs) + 1, 3)
        for step, (k, back) in enumerate(zip(chain.pairs, chain.reversed, strict=True)):
            start, goal = ends[k][::-1] if back else ends[k]
            assert np.linalg.norm(chain.vertices[step] - start) <= join + 1e-12
            assert np.linalg.norm(chain.vertices[step + 1] - goal) <= join + 1e-12


def fewest_strokes(pairs: list[tuple[int, int]]) -> int:
    """The fewest trails that cover a graph's edges once (edges given as node pairs): per
    connected part, half its odd nodes, or one."""
    parent: dict[int, int] = {}

    def root(n: int) -> int:
        parent.setdefault(n, n)
        while parent[n] != n:
            n = parent[n]
        return n

    degree: Counter[int] = Counter()
    for a, b in pairs:
        degree[a] += 1
        degree[b] += 1
        parent[root(a)] = root(b)
    parts: dict[int, int] = {}
    for node, count in degree.items():
        parts[root(node)] = parts.get(root(node), 0) + count % 2
    return sum(max(1, odd // 2) for odd in parts.values())


DIGIT_STROKES = {"0": 1, "1": 1, "2": 1, "3": 2, "4": 2, "5": 1, "6": 1, "7": 1, "8": 1, "9": 1}
"""Seven-segment digits in the fewest strokes: a 3 and a 4 branch at two T-joints (four odd
nodes); every other digit is one path or one loop."""


@pytest.mark.parametrize("digit", list("0123456789"))
def test_every_digit_is_piped_in_its_fewest_strokes(digit: str) -> None:
    ends = lifted(seven_segment(digit, (0.15, 0.09), 0.04))
    chains = chains_of(ends)
    assert_valid(chains, ends)
    assert len(chains) == DIGIT_STROKES[digit]
    if digit == "0":  # a loop: it closes where it started
        assert np.array_equal(chains[0].vertices[0], chains[0].vertices[-1])


def test_a_two_digit_number_is_one_stroke_per_digit_in_reading_order() -> None:
    ends = lifted(seven_segment("27", (0.15, 0.09), 0.04))
    chains = chains_of(ends)
    assert_valid(chains, ends)
    assert [c.pairs for c in chains] == [(0, 1, 2, 3, 4), (5, 6, 7)]
    # the 2 drawn as a hand does: the middle bar is the one segment piped right to left
    assert chains[0].reversed == (False, False, True, False, False)


@pytest.mark.parametrize("points", [5, 6, 7, 8, 9])
def test_star_lines_are_one_loop_per_cycle_of_tips(points: int) -> None:
    """{n/2}: every second tip joined. An odd n is one loop through all n lines, an even n two
    polygons (the 6-pointed star's two triangles) that cross but share no end."""
    ends = lifted(star((0.15, 0.09), 0.04, points))
    chains = chains_of(ends)
    assert_valid(chains, ends)
    assert len(chains) == math.gcd(points, 2)
    for chain in chains:
        assert np.array_equal(chain.vertices[0], chain.vertices[-1])
        assert not any(chain.reversed)  # the design's order already runs round each loop


@pytest.mark.parametrize("points", [5, 6, 7, 8, 9])
def test_a_star_outline_is_one_closed_stroke(points: int) -> None:
    ends = lifted(star((0.15, 0.09), 0.04, points, inner_ratio=0.45))
    (chain,) = chains_of(ends)
    assert chain.pairs == tuple(range(2 * points)) and not any(chain.reversed)
    assert np.array_equal(chain.vertices[0], chain.vertices[-1])


def test_a_spiral_keeps_the_plan_order_even_where_its_segments_are_shorter_than_the_join() -> None:
    """The offline spiral's inner segments are about 1.5 mm long, less than the 2 mm join
    distance: both ends of one segment must never merge (it would vanish)."""
    ends = lifted(spiral((0.15, 0.09), 0.002, 0.035, 3.0, 48))
    lengths = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    assert lengths.min() < JOIN
    (chain,) = chains_of(ends)
    assert chain.pairs == tuple(range(48)) and not any(chain.reversed)
    assert np.array_equal(chain.vertices[:-1], ends[:, 0])
    assert np.array_equal(chain.vertices[-1], ends[-1, 1])


def test_dots_stay_dots_and_lines_alone_stay_as_planned() -> None:
    line = [[0.10, 0.05], [0.14, 0.05]]
    ends = lifted(
        [
            [[0.10, 0.05], [0.10, 0.05]],  # a dot on the line's start
            line,
            [[0.20, 0.05], [0.20, 0.05]],
            [[0.14, 0.09], [0.18, 0.09]],
        ]
    )
    chains = chains_of(ends)
    assert [c.pairs for c in chains] == [(0,), (1,), (2,), (3,)]
    for chain, pair in zip(chains, ends, strict=True):
        assert np.array_equal(chain.vertices, pair) and chain.reversed == (False,)


def test_ends_join_within_half_a_line_width_and_no_further() -> None:
    for gap, joined in ((0.0, True), (0.9 * JOIN, True), (1.1 * JOIN, False), (0.01, False)):
        ends = lifted([[[0.10, 0.05], [0.14, 0.05]], [[0.14 + gap, 0.05], [0.14, 0.09]]])
        chains = chains_of(ends)
        assert len(chains) == (1 if joined else 2), gap
        if joined and gap:  # where they meet is between the two ends
            assert chains[0].vertices[1, 0] == pytest.approx(0.14 + gap / 2)


def test_without_a_line_width_only_ends_that_coincide_join() -> None:
    ends = lifted([[[0.10, 0.05], [0.14, 0.05]], [[0.1405, 0.05], [0.14, 0.09]]])
    assert len(chains_of(ends, join=0.0)) == 2
    ends[1, 0] = ends[0, 1]
    assert len(chains_of(ends, join=0.0)) == 1


def test_lines_on_different_objects_or_heights_never_join() -> None:
    ends = lifted([[[0.10, 0.05], [0.14, 0.05]], [[0.14, 0.05], [0.14, 0.09]]])
    assert len(chains_of(ends, objects=[1, 2])) == 2
    ends[1, :, 2] += 0.01  # a taller cake beside it
    assert len(chains_of(ends)) == 2


def random_drawing(rng: np.random.Generator) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """A random drawing as a VLM might send it: a few random walks on a grid of nodes (they
    cross and share nodes, so they branch), broken into pairs, shuffled, some reversed, every
    end off its node by up to a quarter of the join distance; some dots among them.

    Returns the pairs and, per line pair, its true (start node, goal node)."""
    spacing = 0.01
    nodes = {
        (i, j): np.array([0.05 + i * spacing, 0.03 + j * spacing])
        for i in range(12)
        for j in range(10)
    }
    edges: set[tuple[tuple[int, int], tuple[int, int]]] = set()
    for _ in range(rng.integers(1, 5)):
        here = (int(rng.integers(12)), int(rng.integers(10)))
        for _ in range(rng.integers(1, 12)):
            di, dj = [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, 1)][rng.integers(6)]
            there = (here[0] + di, here[1] + dj)
            if there not in nodes or (there, here) in edges or (here, there) in edges:
                continue
            edges.add((here, there))
            here = there
    number = {node: n for n, node in enumerate(nodes)}
    pairs, truth = [], []
    for a, b in edges:
        if rng.random() < 0.5:
            a, b = b, a
        jitter = rng.normal(size=(2, 2))
        jitter *= (0.25 * JOIN * rng.random((2, 1))) / np.linalg.norm(jitter, axis=1, keepdims=True)
        pairs.append(np.array([nodes[a], nodes[b]]) + jitter)
        truth.append((number[a], number[b]))
    for _ in range(rng.integers(0, 4)):
        spot = nodes[(int(rng.integers(12)), int(rng.integers(10)))] + 0.005
        pairs.append(np.array([spot, spot]))
    order = rng.permutation(len(pairs))
    ends = lifted(np.array(pairs)[order])
    lines = [truth[k] for k in order if k < len(truth)]
    return ends, lines


def test_random_drawings_are_piped_in_their_fewest_strokes() -> None:
    rng = np.random.default_rng(39)
    cases = 0
    for _ in range(300):
        ends, lines = random_drawing(rng)
        if not lines:
            continue
        chains = chains_of(ends)
        assert_valid(chains, ends)
        dots = int((np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1) == 0).sum())
        assert len(chains) == fewest_strokes(lines) + dots
        cases += 1
    assert cases > 250


def test_close_ends_are_found_as_a_brute_force_search_finds_them() -> None:
    from keymps.motion.chains import _close_pairs

    rng = np.random.default_rng(7)
    for count in (0, 1, 2, 50, 400):
        points = rng.uniform(0.0, 0.05, (count, 3))
        points[: count // 2, 0] = 0.02  # many on one x: the sweep's worst case
        found = {tuple(sorted(pair)) for pair in _close_pairs(points, 0.004).tolist()}
        apart = np.linalg.norm(points[:, None] - points[None], axis=2)
        want = {(i, j) for i, j in zip(*np.nonzero(apart <= 0.004), strict=True) if i < j}
        assert found == want
