"""d_boxplot.png: D per case as box plots, one colour per method (the paper's Figs. 9-12 style).

Drawn with OpenCV and NumPy, keymps' own dependencies: every install writes it, and `keymps
eval` spends 20 ms on it instead of matplotlib's 0.4 s import and 0.2 s drawing (docs/
performance.md). The boxes follow the usual convention (matplotlib's and Tukey's): the box spans
the quartiles (NumPy's linear percentiles) with a line at the median, each whisker reaches the
furthest value within 1.5 box lengths of the box, and values beyond are drawn as circles.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from keymps.sorted_values import percentile
from keymps.text_drawing import on_text_thread

WHISKER = 1.5
"""Whiskers reach the furthest value within WHISKER x the interquartile range of the box."""
DPI = 120
HEIGHT_PX = 4 * DPI
PALETTE_RGB = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
)  # fmt: skip
"""The usual ten categorical colours ("tab10"), one per method in name order."""
FILL_ALPHA = 0.6
INK_BGR = (0, 0, 0)
GRID_BGR = (230, 230, 230)
FONT = 0  # cv2.FONT_HERSHEY_SIMPLEX
_SHIFT = 4  # sub-pixel bits for anti-aliased drawing


@dataclass(frozen=True)
class BoxStats:
    """One box: quartiles, median, whisker ends and the values beyond them."""

    q1: float
    median: float
    q3: float
    low: float
    """The lower whisker's end: the smallest value >= q1 - WHISKER * (q3 - q1)."""
    high: float
    fliers: tuple[float, ...]


def box_stats(values: Sequence[float]) -> BoxStats:
    """The statistics one box shows (at least one value)."""
    data = np.sort(np.asarray(values, dtype=float))
    q1, median, q3 = (percentile(data, q) for q in (25, 50, 75))  # NumPy's, without numpy.ma
    reach = WHISKER * (q3 - q1)
    inside = data[(data >= q1 - reach) & (data <= q3 + reach)]
    low = float(inside[0]) if len(inside) else q1
    high = float(inside[-1]) if len(inside) else q3
    fliers = tuple(float(v) for v in data if v < low or v > high)
    return BoxStats(q1, median, q3, min(low, q1), max(high, q3), fliers)


def nice_ticks(low: float, high: float, count: int = 8) -> list[float]:
    """About `count` round values (1, 2, 2.5 or 5 x 10^k apart) covering [low, high]."""
    span = high - low if high > low else max(abs(high), 1.0)
    raw = span / max(1, count - 1)
    magnitude = 10.0 ** math.floor(math.log10(raw))
    step = next(m * magnitude for m in (1, 2, 2.5, 5, 10) if m * magnitude >= raw * 0.999)
    first = math.ceil(low / step - 1e-9)
    last = math.floor(high / step + 1e-9)
    return [round(i * step, 12) for i in range(first, last + 1)]


def _tick_label(value: float, step: float) -> str:
    decimals = max(0, -math.floor(math.log10(step) + 1e-9))
    if abs(round(step / 10.0**-decimals) - step / 10.0**-decimals) > 1e-6:  # 2.5 x 10^k
        decimals += 1
    return f"{value:.{decimals}f}"


def write_box_plot(
    values: dict[str, dict[str, list[float]]], cases: Sequence[str], title: str, path: Path
) -> Path:
    """Draw values[method][case] (D in mm) for `cases` in order and write the PNG to `path`."""
    from keymps.run_files import write_image

    return write_image(path, draw_box_plot(values, cases, title))


def draw_box_plot(
    values: dict[str, dict[str, list[float]]], cases: Sequence[str], title: str
) -> np.ndarray:
    """The box plot as a BGR image, DPI pixels per inch, HEIGHT_PX high."""
    return on_text_thread(_draw_box_plot, values, cases, title)


def _draw_box_plot(
    values: dict[str, dict[str, list[float]]], cases: Sequence[str], title: str
) -> np.ndarray:
    """`draw_box_plot`'s drawing (on the text thread)."""
    methods = sorted(values)
    width_in = min(16.0, max(6.0, 0.45 * len(cases) * len(methods) + 2))
    image = np.full((HEIGHT_PX, round(width_in * DPI), 3), 255, np.uint8)
    stats = {(m, c): box_stats(values[m][c]) for m in methods for c in cases if values[m].get(c)}
    low, high = _value_range(list(stats.values()))
    ticks, labels = _value_ticks(low, high)
    axes = _plot_area(image.shape[1], image.shape[0], title, labels, (low, high), len(cases))
    _draw_value_grid(image, axes, ticks, labels)
    _draw_boxes(image, axes, stats, methods, cases)
    _draw_case_ticks(image, axes, cases)
    _draw_frame_and_titles(image, axes, title)
    _legend(image, methods, axes.left + axes.width - 10, axes.top + 10)
    return image


_TICK_SCALE, _LABEL_SCALE, _TITLE_SCALE = 0.42, 0.48, 0.55
"""OpenCV font scales of the tick labels, the axis labels and the title."""


@dataclass(frozen=True)
class _PlotArea:
    """The plot's rectangle in the image (pixels) and what its axes show: values low-high (mm)
    upwards, case positions 0 to `cases` - 1 left to right."""

    left: int
    top: int
    width: int
    height: int
    low: float
    high: float
    cases: int

    def y(self, value: float) -> float:
        """The pixel row of a value (mm)."""
        return self.top + self.height * (self.high - value) / (self.high - self.low)

    def x(self, position: float) -> float:
        """The pixel column of a case position (the case's number; boxes sit beside it)."""
        return self.left + self.width * (position + 0.75) / (self.cases + 0.5)


def _value_range(stats: list[BoxStats]) -> tuple[float, float]:
    """The values (mm) the axis spans: everything the boxes reach, 5 % more on each side."""
    reached = [v for s in stats for v in (s.low, s.high, *s.fliers)]
    low, high = (min(reached), max(reached)) if reached else (0.0, 1.0)
    margin = 0.05 * (high - low) if high > low else max(0.05 * abs(high), 0.05)
    return low - margin, high + margin


def _value_ticks(low: float, high: float) -> tuple[list[float], list[str]]:
    """The round values inside low-high and their labels, all with one number of decimals."""
    ticks = [t for t in nice_ticks(low, high) if low <= t <= high]
    step = ticks[1] - ticks[0] if len(ticks) > 1 else max(abs(high), 1.0)
    return ticks, [_tick_label(t, step) for t in ticks]


def _plot_area(
    width: int, height: int, title: str, labels: list[str], span: tuple[float, float], cases: int
) -> _PlotArea:
    """The plot's rectangle in a width x height image: room on the left for the axis label and
    the widest tick label, above for the title, below for the case labels."""
    import cv2

    label_h = cv2.getTextSize("Dg", FONT, _LABEL_SCALE, 1)[0][1]
    widest = max((cv2.getTextSize(s, FONT, _TICK_SCALE, 1)[0][0] for s in labels), default=0)
    left = 12 + label_h + 10 + widest + 8
    top = 16 + cv2.getTextSize(title, FONT, _TITLE_SCALE, 1)[0][1] + 14
    right, bottom = 18, 62
    return _PlotArea(left, top, width - left - right, height - top - bottom, *span, cases)


def _text(image: np.ndarray, label: str, x: float, y: float, scale: float, anchor: str) -> None:
    """Black text vertically centred on y, its `anchor` (left, centre or right) at x."""
    import cv2

    (w, h), _ = cv2.getTextSize(label, FONT, scale, 1)
    dx = {"centre": -w / 2, "right": -w, "left": 0.0}[anchor]
    cv2.putText(image, label, (round(x + dx), round(y + h / 2)), FONT, scale, INK_BGR, 1,
                cv2.LINE_AA)  # fmt: skip


def _draw_value_grid(
    image: np.ndarray, axes: _PlotArea, ticks: list[float], labels: list[str]
) -> None:
    """A grid line, a tick and its label at each tick value."""
    import cv2

    for tick, label in zip(ticks, labels, strict=True):
        y = axes.y(tick)
        row = round(y)
        cv2.line(image, (axes.left, row), (axes.left + axes.width, row), GRID_BGR, 1)
        cv2.line(image, (axes.left - 5, row), (axes.left, row), INK_BGR, 1)
        _text(image, label, axes.left - 8, y, _TICK_SCALE, "right")


def _draw_boxes(
    image: np.ndarray,
    axes: _PlotArea,
    stats: dict[tuple[str, str], BoxStats],
    methods: list[str],
    cases: Sequence[str],
) -> None:
    """Each case's boxes side by side, one colour per method (in the order of `methods`)."""
    box_w = 0.8 / max(1, len(methods))
    for index, method in enumerate(methods):
        fill = _blend(PALETTE_RGB[index % len(PALETTE_RGB)])
        for number, case in enumerate(cases):
            box = stats.get((method, case))
            if box is not None:
                centre = number + (index - (len(methods) - 1) / 2) * box_w
                half_width = axes.x(box_w * 0.45) - axes.x(0)
                _draw_box(image, box, axes.x(centre), half_width, axes.y, fill)


def _draw_case_ticks(image: np.ndarray, axes: _PlotArea, cases: Sequence[str]) -> None:
    """Every case has its tick; labels are written every `stride` cases if they would overlap."""
    import cv2

    label_w = max((cv2.getTextSize(c, FONT, _TICK_SCALE, 1)[0][0] for c in cases), default=0) + 8
    stride = max(1, math.ceil(label_w / (axes.x(1) - axes.x(0))))
    bottom = axes.top + axes.height
    for number, case in enumerate(cases):
        x = axes.x(number)
        cv2.line(image, (round(x), bottom), (round(x), bottom + 5), INK_BGR, 1)
        if number % stride == 0:
            _text(image, case, x, bottom + 18, _TICK_SCALE, "centre")


def _draw_frame_and_titles(image: np.ndarray, axes: _PlotArea, title: str) -> None:
    """The plot's frame, the axis labels and the title."""
    import cv2

    height, width = image.shape[:2]
    right, bottom = axes.left + axes.width, axes.top + axes.height
    cv2.rectangle(image, (axes.left, axes.top), (right, bottom), INK_BGR, 1)
    _text(image, "case", axes.left + axes.width / 2, height - 16, _LABEL_SCALE, "centre")
    label_h = cv2.getTextSize("Dg", FONT, _LABEL_SCALE, 1)[0][1]
    _text(image, title, width / 2, 16 + label_h / 2 + 4, _TITLE_SCALE, "centre")
    _vertical_label(image, "D (mm)", 12, axes.top + axes.height / 2, _LABEL_SCALE)


def _blend(rgb: tuple[int, int, int]) -> tuple[int, int, int]:
    """The colour at FILL_ALPHA over white, as BGR."""
    r, g, b = (round(255 + FILL_ALPHA * (c - 255)) for c in rgb)
    return b, g, r


def _draw_box(
    image: np.ndarray,
    box: BoxStats,
    x: float,
    half_width: float,
    y: Callable[[float], float],
    fill: tuple[int, int, int],
) -> None:
    """One box centred at pixel column x; `y` maps a value (mm) to its pixel row."""
    import cv2

    scale = 1 << _SHIFT

    def point(px: float, py: float) -> tuple[int, int]:
        return round(px * scale), round(py * scale)

    cap = half_width / 2
    for end, edge in ((box.low, box.q1), (box.high, box.q3)):
        cv2.line(image, point(x, y(edge)), point(x, y(end)), INK_BGR, 1, cv2.LINE_AA, _SHIFT)
        cv2.line(image, point(x - cap, y(end)), point(x + cap, y(end)), INK_BGR, 1, cv2.LINE_AA,
                 _SHIFT)  # fmt: skip
    corners = np.array(
        [point(x - half_width, y(box.q3)), point(x + half_width, y(box.q3)),
         point(x + half_width, y(box.q1)), point(x - half_width, y(box.q1))], np.int32,
    )  # fmt: skip
    cv2.fillPoly(image, [corners], fill, cv2.LINE_AA, _SHIFT)
    cv2.polylines(image, [corners], True, INK_BGR, 1, cv2.LINE_AA, _SHIFT)
    cv2.line(image, point(x - half_width, y(box.median)), point(x + half_width, y(box.median)),
             INK_BGR, 2, cv2.LINE_AA, _SHIFT)  # fmt: skip
    for flier in box.fliers:
        cv2.circle(image, point(x, y(flier)), 3 * scale, INK_BGR, 1, cv2.LINE_AA, _SHIFT)


def _vertical_label(image: np.ndarray, label: str, x: int, centre_y: float, scale: float) -> None:
    import cv2

    (w, h), base = cv2.getTextSize(label, FONT, scale, 1)
    patch = np.full((h + base + 2, w + 2, 3), 255, np.uint8)
    cv2.putText(patch, label, (1, h + 1), FONT, scale, INK_BGR, 1, cv2.LINE_AA)
    turned = cv2.rotate(patch, cv2.ROTATE_90_COUNTERCLOCKWISE)
    top = max(0, round(centre_y - turned.shape[0] / 2))
    image[top : top + turned.shape[0], x : x + turned.shape[1]] = turned


def _legend(image: np.ndarray, methods: list[str], right: int, top: int) -> None:
    import cv2

    scale = 0.4
    sizes = [cv2.getTextSize(m, FONT, scale, 1)[0] for m in methods]
    line_h = max(h for _, h in sizes) + 8
    width = 10 + 26 + 6 + max(w for w, _ in sizes) + 10
    left = right - width
    cv2.rectangle(image, (left, top), (right, top + 8 + line_h * len(methods)), (255, 255, 255), -1)
    cv2.rectangle(image, (left, top), (right, top + 8 + line_h * len(methods)), (200, 200, 200), 1)
    for index, (method, (_, h)) in enumerate(zip(methods, sizes, strict=True)):
        y = top + 4 + line_h * index + line_h // 2
        colour = _blend(PALETTE_RGB[index % len(PALETTE_RGB)])
        cv2.rectangle(image, (left + 10, y - 4), (left + 36, y + 4), colour, -1)
        cv2.putText(image, method, (left + 42, y + h // 2), FONT, scale, INK_BGR, 1, cv2.LINE_AA)
