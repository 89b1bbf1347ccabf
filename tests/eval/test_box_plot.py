"""keymps.eval.box_plot: the eval's d_boxplot.png, drawn with OpenCV (no matplotlib needed)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from keymps.eval.box_plot import (
    DPI,
    HEIGHT_PX,
    PALETTE_RGB,
    _blend,
    box_stats,
    draw_box_plot,
    nice_ticks,
)


def _samples(rng: np.random.Generator) -> list[float]:
    """D values as an eval makes them: a few to a hundred runs, skewed, with ties and outliers."""
    size = int(rng.choice([1, 2, 3, 4, 5, 8, 10, 20, 50, 100]))
    kind = rng.integers(4)
    if kind == 0:
        values = rng.lognormal(0.0, float(rng.uniform(0.1, 1.0)), size)
    elif kind == 1:
        values = rng.normal(2.0, 0.5, size)
    elif kind == 2:  # repeated runs of a deterministic backend: many equal values
        values = np.round(rng.normal(1.5, 0.3, size), 1)
    else:  # mostly tight, with a few far off
        values = np.concatenate([rng.normal(1.0, 0.05, size), rng.uniform(3, 9, size // 10)])
    return [float(v) for v in values]


def test_the_box_statistics_are_matplotlibs_on_generated_samples() -> None:
    cbook = pytest.importorskip("matplotlib.cbook")
    rng = np.random.default_rng(20261202)
    for _ in range(300):
        values = _samples(rng)
        mine = box_stats(values)
        theirs = cbook.boxplot_stats(np.asarray(values))[0]
        assert mine.q1 == pytest.approx(theirs["q1"], abs=1e-12)
        assert mine.median == pytest.approx(theirs["med"], abs=1e-12)
        assert mine.q3 == pytest.approx(theirs["q3"], abs=1e-12)
        assert mine.low == pytest.approx(theirs["whislo"], abs=1e-12)
        assert mine.high == pytest.approx(theirs["whishi"], abs=1e-12)
        assert sorted(mine.fliers) == pytest.approx(sorted(theirs["fliers"].tolist()), abs=1e-12)


def test_ticks_are_round_evenly_spaced_and_cover_the_range() -> None:
    rng = np.random.default_rng(7)
    for _ in range(500):
        low = float(rng.uniform(-5, 50)) * 10.0 ** int(rng.integers(-3, 3))
        high = low + float(rng.uniform(1e-3, 100)) * 10.0 ** int(rng.integers(-2, 2))
        ticks = nice_ticks(low, high)
        assert 3 <= len(ticks) <= 12, (low, high, ticks)
        steps = np.diff(ticks)
        assert np.allclose(steps, steps[0], rtol=1e-9)
        mantissa = steps[0] / 10.0 ** math.floor(math.log10(steps[0]) + 1e-12)
        assert any(abs(mantissa - m) < 1e-6 for m in (1, 2, 2.5, 5, 10)), (ticks, mantissa)
        assert ticks[0] >= low - 1e-9 and ticks[-1] <= high + 1e-9
        assert ticks[0] - steps[0] < low and ticks[-1] + steps[0] > high


def _components(image: np.ndarray, bgr: tuple[int, int, int]) -> list[tuple[int, int, int]]:
    """(left x, top y, height) of each region painted exactly `bgr`, left to right."""
    import cv2

    mask = np.all(image == np.array(bgr, np.uint8), axis=2).astype(np.uint8)
    count, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=4)
    found = [(int(s[0]), int(s[1]), int(s[3])) for s in stats[1:count] if s[4] >= 6]
    return sorted(found)


def test_every_box_is_drawn_in_its_methods_colour_in_case_order() -> None:
    rng = np.random.default_rng(11)
    for _ in range(30):
        methods = ["keymps", "vlm-keypoint", "vlm-direct"][: int(rng.integers(1, 4))]
        cases = [str(i + 1) for i in range(int(rng.integers(1, 16)))]
        values = {m: {c: _samples(rng) for c in cases if rng.random() < 0.9} for m in methods}
        values = {m: v for m, v in values.items() if v}
        if not values:
            continue
        image = draw_box_plot(values, cases, "generated")
        width_in = min(16.0, max(6.0, 0.45 * len(cases) * len(values) + 2))
        assert image.shape == (HEIGHT_PX, round(width_in * DPI), 3)
        spans = [
            (m, c, box_stats(values[m][c])) for m in sorted(values) for c in cases if c in values[m]
        ]
        reached = [v for _, _, s in spans for v in (s.low, s.high, *s.fliers)]
        scale = HEIGHT_PX / (max(reached) - min(reached) + 1e-9)  # > the plot's px per mm
        for index, method in enumerate(sorted(values)):
            fill = _blend(PALETTE_RGB[index])
            boxes = [(c, s) for m, c, s in spans if m == method]
            # boxes tall enough to show their fill inside the outline and the median line
            tall = [
                (c, s)
                for c, s in boxes
                if (s.q3 - s.q1) * scale * 0.5 > 8 and min(s.q3 - s.median, s.median - s.q1) > 0
            ]
            painted = _components(image, fill)
            columns = [x for x, _, _ in painted]
            assert columns == sorted(columns)
            assert len(painted) >= len(tall), (method, len(painted), len(tall))
            assert len(painted) <= 2 * len(boxes) + 1  # (the legend's swatch, median splits)


def test_a_case_without_values_leaves_a_gap_and_the_legend_has_a_swatch() -> None:
    values = {"keymps": {"1": [1.0, 1.2, 1.4], "3": [2.0, 2.5, 3.0]}}
    image = draw_box_plot(values, ["1", "2", "3"], "gap")
    fill = _blend(PALETTE_RGB[0])
    painted = _components(image, fill)  # each box in two parts: the median line splits it
    width = image.shape[1]
    legend = [p for p in painted if p[0] > width - 200 and p[1] < 100]
    boxes = sorted({p[0] for p in painted if p not in legend})
    assert len(legend) == 1 and len(boxes) == 2
    middle = (boxes[0] + boxes[1]) // 2  # where case 2 would be
    column = image[:, middle - 3 : middle + 3]
    assert not np.all(column == np.array(fill, np.uint8), axis=2).any()


def test_records_without_a_finite_d_are_left_out_of_the_plot(tmp_path: Path) -> None:
    from keymps.eval.report import write_box_plots
    from keymps.eval.suites import load_suite

    suite = load_suite("cutting_sim")
    broken = [
        {"method": "keymps", "case": "1", "d_mm": float("nan")},
        {"method": "keymps", "case": "2", "d_mm": None},
        {"method": "keymps", "case": "3", "d_mm": float("inf")},
    ]
    assert write_box_plots(broken, suite, tmp_path) == []  # nothing to draw: no file
    kept = write_box_plots(
        [*broken, {"method": "keymps", "case": "1", "d_mm": 1.5}], suite, tmp_path
    )
    assert kept == [tmp_path / "d_boxplot.png"] and kept[0].stat().st_size > 1000
