"""Icing deposits from nozzle paths: dots and lines, strokes and loops, merging, on the top."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from keymps.outcome.deposits import DOT_DIAMETER_FACTOR, deposits_of, merges
from keymps.outcome.predict import Food

LINE = 0.004
CAKE = Food(1, 0.06, np.array([[0.0, 0.0], [0.2, 0.0], [0.2, 0.2], [0.0, 0.2]]))


def _dot(x: float, y: float, pair: int) -> tuple[int, Food, np.ndarray]:
    """A nozzle that descends to 1 mm above the top at (x, y), dwells and rises."""
    z = np.array([0.065, 0.063, 0.061, 0.061, 0.061, 0.063, 0.065])
    return pair, CAKE, np.column_stack([np.full(7, x), np.full(7, y), z])


def _line(a: np.ndarray, b: np.ndarray, pair: int) -> tuple[int, Food, np.ndarray]:
    t = np.linspace(0.0, 1.0, 40)[:, None]
    xy = a + t * (b - a)
    return pair, CAKE, np.column_stack([xy, np.full(40, 0.061)])


@settings(max_examples=150, deadline=None)
@given(
    count=st.integers(3, 60),
    radius=st.floats(0.02, 0.08),
)
def test_a_ring_of_dots_merges_exactly_when_the_dots_touch(count, radius, fuzz_counter):
    angles = 2 * math.pi * np.arange(count) / count
    work = [_dot(0.1 + radius * math.cos(a), 0.1 + radius * math.sin(a), k)
            for k, a in enumerate(angles)]  # fmt: skip
    deposits, strokes, loops = deposits_of(work, LINE)
    assert [d.kind for d in deposits] == ["dot"] * count and strokes == count and loops == 0
    spacing = 2 * radius * math.sin(math.pi / count)
    merging = merges(deposits, LINE)
    touching = spacing < DOT_DIAMETER_FACTOR * LINE
    fuzz_counter.add("outcome/rings of dots", (count, radius), f"merge {touching}")
    if abs(spacing - DOT_DIAMETER_FACTOR * LINE) > 1e-6:
        assert bool(merging) == touching
    if merging:
        assert math.isclose(merging[0].gap_m, spacing, rel_tol=1e-6)


def test_joined_lines_are_one_stroke_and_a_closed_one_is_a_loop():
    corners = [np.array(p) for p in ((0.05, 0.05), (0.15, 0.05), (0.15, 0.15), (0.05, 0.15))]
    square = [_line(corners[k], corners[(k + 1) % 4], k) for k in range(4)]
    apart = [_line(np.array([0.05, 0.18]), np.array([0.15, 0.18]), 4)]
    deposits, strokes, loops = deposits_of(square + apart, LINE)
    assert [d.kind for d in deposits] == ["line"] * 5
    assert (strokes, loops) == (2, 1) and len({d.stroke for d in deposits[:4]}) == 1
    assert merges(deposits, LINE) == []  # corners are joints, the far line is 30 mm off
    near = [_line(np.array([0.05, 0.153]), np.array([0.15, 0.153]), 4)]
    deposits, _, _ = deposits_of(square + near, LINE)
    (merge,) = merges(deposits, LINE)
    assert merge.kind == "lines" and merge.gap_m < LINE


def test_a_ring_piped_as_one_stroke_is_a_loop_and_a_line_there_and_back_is_not():
    """Icing lines that meet are piped as one work piece (keymps.motion.chains): a ring is
    then one line that ends where it starts (it counted no loop, and "2 rings" was refused)."""
    angles = np.linspace(0.0, 2 * math.pi, 73)
    rings = []
    for k, radius in enumerate((0.03, 0.06)):
        xy = 0.1 + radius * np.c_[np.cos(angles), np.sin(angles)]
        rings.append((k, CAKE, np.column_stack([xy, np.full(len(xy), 0.061)])))
    deposits, strokes, loops = deposits_of(rings, LINE)
    assert [d.kind for d in deposits] == ["line", "line"] and (strokes, loops) == (2, 2)
    there = np.linspace(0.05, 0.15, 30)
    back = np.r_[there, there[::-1]]
    to_and_fro = np.column_stack([back, np.full(60, 0.1), np.full(60, 0.061)])
    assert deposits_of([(0, CAKE, to_and_fro)], LINE)[1:] == (1, 0)


def test_a_dot_piped_a_little_off_its_place_is_still_a_dot_and_icing_off_the_top_is_named():
    off_place = _line(np.array([0.1, 0.1]), np.array([0.103, 0.1]), 0)  # 3 mm, joined to none
    edge = _dot(0.199, 0.1, 1)  # its disc hangs 3 mm over the edge
    high = (2, CAKE, np.column_stack([np.full(5, 0.05), np.full(5, 0.05), np.full(5, 0.08)]))
    deposits, strokes, _ = deposits_of([off_place, edge, high], LINE)
    assert [(d.kind, d.pair_index, d.on_top) for d in deposits] == [
        ("dot", 0, True),
        ("dot", 1, False),
    ]  # the nozzle 20 mm above the top deposits nothing
    assert strokes == 2 and deposits[0].width_m == DOT_DIAMETER_FACTOR * LINE
