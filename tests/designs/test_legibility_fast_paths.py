"""Merging icing strokes: the near-box search against every pair of strokes.

Each fast path is held against the implementation it replaced, on generated inputs."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

RNG_SEED = 20261201


def _merging_strokes_pair_by_pair(pairs: np.ndarray, line_width: float) -> Any:
    """merging_strokes as it was: every pair of strokes, points grouped one by one."""
    from keymps.designs.legibility import MERGE_PATH_FACTOR, _cross

    pairs = np.asarray(pairs, float).reshape(-1, 2, 2)
    ends = pairs.reshape(-1, 2)
    tolerance = 1e-6 * max(1.0, float(np.abs(ends).max()))
    nodes: list[np.ndarray] = []
    node_of: list[int] = []
    for point in ends:
        for k, node in enumerate(nodes):
            if np.abs(node - point).max() <= tolerance:
                node_of.append(k)
                break
        else:
            nodes.append(point)
            node_of.append(len(nodes) - 1)
    lengths = np.linalg.norm(pairs[:, 1] - pairs[:, 0], axis=1)
    between = np.full((len(nodes), len(nodes)), np.inf)
    np.fill_diagonal(between, 0.0)
    for k, length in enumerate(lengths):
        a, b = node_of[2 * k], node_of[2 * k + 1]
        between[a, b] = between[b, a] = min(between[a, b], length)
    for k in range(len(nodes)):
        between = np.minimum(between, between[:, k : k + 1] + between[k : k + 1, :])
    step = line_width / 4
    samples = [np.linspace(0.0, 1.0, max(2, math.ceil(n / step) + 1)) for n in lengths]
    points = [p[0] + f[:, None] * (p[1] - p[0]) for p, f in zip(pairs, samples, strict=True)]
    along = [f * n for f, n in zip(samples, lengths, strict=True)]
    best = None
    for i in range(len(pairs)):
        for j in range(i + 1, len(pairs)):
            gaps = np.linalg.norm(points[i][:, None, :] - points[j][None, :, :], axis=2)
            if gaps.min() >= line_width or _cross(pairs[i], pairs[j]):
                continue
            ui, uj = along[i][:, None], along[j][None, :]
            ri, rj = lengths[i] - ui, lengths[j] - uj
            ai, bi, aj, bj = node_of[2 * i], node_of[2 * i + 1], node_of[2 * j], node_of[2 * j + 1]
            path = np.minimum.reduce(
                [ui + between[ai, aj] + uj, ui + between[ai, bj] + rj,
                 ri + between[bi, aj] + uj, ri + between[bi, bj] + rj]
            )  # fmt: skip
            merging = (gaps < line_width) & (path > MERGE_PATH_FACTOR * line_width)
            if merging.any():
                gap = float(gaps[merging].min())
                if best is None or gap < best[0]:
                    a, b = np.argwhere(merging & (gaps == gap))[0]
                    best = (gap, (points[i][a] + points[j][b]) / 2)
    return best


def test_merging_strokes_from_near_boxes_match_every_pair_of_strokes() -> None:
    from keymps.designs.legibility import merging_strokes

    rng = np.random.default_rng(RNG_SEED + 41)
    found = 0
    for case in range(80):
        count = int(rng.integers(1, 25))
        scale = float(rng.choice([1.0, 100.0, 600.0]))  # metres or pixels
        starts = rng.uniform(0, scale, (count, 2))
        lengths = np.where(rng.random(count) < 0.5, 0.0, rng.uniform(0, 0.3 * scale, count))
        turns = rng.uniform(0, 2 * np.pi, count)
        goals = starts + lengths[:, None] * np.column_stack([np.cos(turns), np.sin(turns)])
        pairs = np.stack([starts, goals], axis=1)
        if case % 3 == 0 and count > 2:  # strokes sharing ends: a polyline
            pairs[1:, 0] = pairs[:-1, 1]
        width = float(rng.uniform(0.005, 0.08)) * scale
        got = merging_strokes(pairs, width)
        expected = _merging_strokes_pair_by_pair(pairs, width)
        assert (got is None) == (expected is None)
        if got is not None:
            assert got[0] == expected[0] and np.array_equal(got[1], expected[1])
            found += 1
    assert 10 < found < 70
