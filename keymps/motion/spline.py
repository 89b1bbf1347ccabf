"""Not-a-knot cubic splines through joint vectors, with derivatives, in numpy.

The timing maps the path parameter s to joints through one spline per stroke. This is the
spline scipy.interpolate.CubicSpline builds by default (bc_type 'not-a-knot', axis 0), written
out so that a run does not import scipy.interpolate (over half a second on a busy machine) for
it: the same linear system for the knot slopes (solved by the tridiagonal recursion), the same
piecewise polynomial, the same extrapolation past the ends. tests/*/test_*_fast_paths.py compares
the two.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np


class CubicSpline:
    """y(x) through knots x (n,) strictly increasing and values y (n, ...); call as f(x, nu)."""

    def __init__(self, x: np.ndarray, y: np.ndarray):
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        if x.ndim != 1 or len(x) < 2 or len(y) != len(x):
            raise ValueError("CubicSpline: x must be (n,) with n >= 2 and y (n, ...)")
        h = np.diff(x)
        if not np.all(h > 0):
            raise ValueError("CubicSpline: x must be strictly increasing")
        shape = y.shape[1:]
        values = y.reshape(len(x), -1)
        secant = np.diff(values, axis=0) / h[:, None]
        slopes = _knot_slopes(h, secant)
        t = (slopes[:-1] + slopes[1:] - 2 * secant) / h[:, None]
        self.x = x
        self.shape = shape
        self.c = np.empty((4, len(h), values.shape[1]))
        self.c[0] = t / h[:, None]
        self.c[1] = (secant - slopes[:-1]) / h[:, None] - t
        self.c[2] = slopes[:-1]
        self.c[3] = values[:-1]

    def with_derivatives(self, at: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Values, first and second derivatives at `at` (m,), sharing one interval search."""
        at = np.asarray(at, dtype=float)
        interval = np.clip(np.searchsorted(self.x, at, side="right") - 1, 0, len(self.x) - 2)
        t = (at - self.x[interval])[:, None]
        c3, c2, c1, c0 = (self.c[k][interval] for k in range(4))
        value = ((c3 * t + c2) * t + c1) * t + c0
        first = (3 * c3 * t + 2 * c2) * t + c1
        second = 6 * c3 * t + 2 * c2
        shape = (len(at), *self.shape)
        return value.reshape(shape), first.reshape(shape), second.reshape(shape)

    def derivatives(self, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First and second derivatives at `at` (m,): `with_derivatives` without the values."""
        at = np.asarray(at, dtype=float)
        interval = np.clip(np.searchsorted(self.x, at, side="right") - 1, 0, len(self.x) - 2)
        t = (at - self.x[interval])[:, None]
        c3, c2, c1 = (self.c[k][interval] for k in range(3))
        first = (3 * c3 * t + 2 * c2) * t + c1
        second = 6 * c3 * t + 2 * c2
        shape = (len(at), *self.shape)
        return first.reshape(shape), second.reshape(shape)

    def __call__(self, at: np.ndarray, nu: int = 0) -> np.ndarray:
        """Values (nu = 0) or the nu-th derivative (1, 2, 3) at `at` (m,): (m, ...)."""
        at = np.asarray(at, dtype=float)
        interval = np.clip(np.searchsorted(self.x, at, side="right") - 1, 0, len(self.x) - 2)
        t = (at - self.x[interval])[:, None]
        c3, c2, c1, c0 = (self.c[k][interval] for k in range(4))  # c3 multiplies t**3
        if nu == 0:
            out = ((c3 * t + c2) * t + c1) * t + c0
        elif nu == 1:
            out = (3 * c3 * t + 2 * c2) * t + c1
        elif nu == 2:
            out = 6 * c3 * t + 2 * c2
        elif nu == 3:
            out = np.broadcast_to(6 * c3, (len(at), c3.shape[1])).copy()
        else:
            raise ValueError(f"CubicSpline: derivative order {nu} is not 0 to 3")
        return out.reshape(len(at), *self.shape)


PADDING_SLACK = 4096
"""Rows of padding a group of slope systems may hold beyond twice its own (`many_splines`)."""


def many_splines(knots: list[np.ndarray], values: list[np.ndarray]) -> list[CubicSpline]:
    """`CubicSpline(knots[k], values[k])` for every k, the same splines to the last bit, built
    in one pass: the slope systems solved side by side (`_thomas_side_by_side`) and the
    coefficients of all intervals in one array (each spline's a view of it). Splines of fewer
    than four knots (solved in closed form) are built one by one."""
    if len(knots) != len(values):
        raise ValueError("many_splines: as many knot arrays as value arrays are needed")
    x = [np.asarray(k, dtype=float) for k in knots]
    y = [np.asarray(v, dtype=float) for v in values]
    out: list[CubicSpline | None] = [None] * len(x)
    batch = []
    for k, (knots_k, values_k) in enumerate(zip(x, y, strict=True)):
        if knots_k.ndim == 1 and len(knots_k) >= 4 and len(values_k) == len(knots_k):
            batch.append(k)
        else:
            out[k] = CubicSpline(knots_k, values_k)
    shapes = {y[k].shape[1:] for k in batch}
    if len(shapes) > 1:
        return [CubicSpline(k, v) for k, v in zip(x, y, strict=True)]
    # Systems are solved side by side, padded to the longest of their group: a group takes
    # the next shorter system while its padded rows stay under twice its real rows (plus
    # PADDING_SLACK), so that one long stroke among many short ones costs no memory.
    groups: list[list[int]] = []
    padded = real = 0
    for k in sorted(batch, key=lambda k: -len(x[k])):
        if groups and (len(groups[-1]) + 1) * padded <= 2 * (real + len(x[k])) + PADDING_SLACK:
            groups[-1].append(k)
            real += len(x[k])
        else:
            groups.append([k])
            padded = real = len(x[k])
    for group in groups:
        built = _splines_side_by_side([x[k] for k in group], [y[k] for k in group])
        for k, spline in zip(group, built, strict=True):
            out[k] = spline
    return [spline for spline in out if spline is not None]


def _splines_side_by_side(x: list[np.ndarray], y: list[np.ndarray]) -> list[CubicSpline]:
    """`many_splines` of splines of at least four knots each."""
    shape = y[0].shape[1:]
    sizes = np.array([len(k) for k in x])
    all_x = np.concatenate(x)
    all_y = np.concatenate([v.reshape(len(v), -1) for v in y])
    knot_end = np.cumsum(sizes)
    not_last = np.ones(len(all_x), dtype=bool)  # knots that start an interval
    not_last[knot_end - 1] = False
    h = np.diff(all_x)[not_last[:-1]]  # without the steps from one spline's end to the next
    if not np.all(h > 0):
        raise ValueError("CubicSpline: x must be strictly increasing")
    secant = np.diff(all_y, axis=0)[not_last[:-1]] / h[:, None]
    slopes = _many_knot_slopes(h, secant, sizes)
    left = np.flatnonzero(not_last)
    slope_left = slopes[left]
    t = (slope_left + slopes[left + 1] - 2 * secant) / h[:, None]
    c = np.empty((4, len(h), all_y.shape[1]))
    c[0] = t / h[:, None]
    c[1] = (secant - slope_left) / h[:, None] - t
    c[2] = slope_left
    c[3] = all_y[left]
    interval_end = np.cumsum(sizes - 1)
    out = []
    for knots_k, start, end in zip(x, interval_end - (sizes - 1), interval_end, strict=True):
        spline = CubicSpline.__new__(CubicSpline)
        spline.x, spline.shape, spline.c = knots_k, shape, c[:, start:end]
        out.append(spline)
    return out


def _many_knot_slopes(h: np.ndarray, secant: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """`_knot_slopes` of splines of `sizes` (each >= 4) knots whose intervals are end to end
    in h and secant: the same rows, solved side by side; the knots' slopes end to end."""
    count, longest = len(sizes), int(sizes.max())
    interval_end = np.cumsum(sizes - 1)
    first = interval_end - (sizes - 1)  # each spline's first interval
    # row i of spline k at [k, i], padded to the longest with rows of the identity
    lower, upper = np.zeros((count, longest)), np.zeros((count, longest))
    diagonal = np.ones((count, longest))
    rhs = np.zeros((count, longest, secant.shape[1]))
    inner = sizes - 2  # rows 1 .. n - 2
    spline_of = np.repeat(np.arange(count), inner)
    before = np.arange(len(spline_of)) - np.repeat(np.cumsum(inner) - inner - first, inner)
    after = before + 1  # row i: intervals i - 1 and i
    rows = (spline_of, before - first[spline_of] + 1)
    lower[rows] = h[after]
    diagonal[rows] = 2 * (h[before] + h[after])
    upper[rows] = h[before]
    rhs[rows] = 3 * (h[after, None] * secant[before] + h[before, None] * secant[after])
    # not-a-knot: the third derivative is continuous across the second and last-but-one knots
    every = np.arange(count)
    h0, h1, s0, s1 = h[first], h[first + 1], secant[first], secant[first + 1]
    diagonal[every, 0], upper[every, 0] = h1, h0 + h1
    up = upper[every, 0]
    square = np.array([v**2 for v in h0])  # as the scalar h[0] ** 2 of `_knot_slopes`
    rhs[every, 0] = (((h0 + 2 * up) * h1)[:, None] * s0 + square[:, None] * s1) / up[:, None]
    last = sizes - 1
    hl, hm = h[interval_end - 1], h[interval_end - 2]
    sl, sm = secant[interval_end - 1], secant[interval_end - 2]
    diagonal[every, last], lower[every, last] = hm, hl + hm
    low = lower[every, last]
    square = np.array([v**2 for v in hl])
    rhs[every, last] = (square[:, None] * sm + ((2 * low + hl) * hm)[:, None] * sl) / low[:, None]
    solved = _thomas_side_by_side(lower, diagonal, upper, rhs, sizes)
    return solved[np.arange(longest)[None, :] < sizes[:, None]]


def _thomas_side_by_side(
    lower: np.ndarray, diagonal: np.ndarray, upper: np.ndarray, rhs: np.ndarray, sizes: np.ndarray
) -> np.ndarray:
    """`_thomas` of many systems at once: row i of every system in one array operation, the
    same operations per value; system k's rows are [k, :sizes[k]], padded with identity rows
    (whose forward values are exactly +0.0)."""
    count, longest = diagonal.shape
    low, mid, up = lower.T.copy(), diagonal.T.copy(), upper.T.copy()
    low_column = low[:, :, None]
    right = rhs.transpose(1, 0, 2).copy()
    scale = 1.0 / mid[0]
    ratio = up[0] * scale
    previous = right[0] * scale[:, None]
    forward, ratios = [previous], [ratio]
    for i in range(1, longest):
        scale = 1.0 / (mid[i] - low[i] * ratio)
        ratio = up[i] * scale
        previous = (right[i] - low_column[i] * previous) * scale[:, None]
        forward.append(previous)
        ratios.append(ratio)
    # A system's last row is its forward value as it is: with a +0.0 ratio there (and +0.0
    # below it) the subtraction leaves it unchanged, -0.0 included.
    factor = np.array(ratios)
    factor[np.arange(longest)[:, None] >= (sizes - 1)[None, :]] = 0.0
    factor_column = factor[:, :, None]
    after = forward[-1]
    out = [after]
    for i in range(longest - 2, -1, -1):
        after = forward[i] - factor_column[i] * after
        out.append(after)
    return np.array(out[::-1]).transpose(1, 0, 2)


def _knot_slopes(h: np.ndarray, secant: np.ndarray) -> np.ndarray:
    """(n, d) first derivatives at the knots of the not-a-knot spline."""
    n = len(h) + 1
    if n == 2:  # a straight line
        return np.vstack([secant[0], secant[0]])
    if n == 3:  # not-a-knot on three points: the parabola through them
        a = np.array(
            [[1.0, 1.0, 0.0], [h[1], 2 * (h[0] + h[1]), h[0]], [0.0, 1.0, 1.0]],
        )
        b = np.vstack([2 * secant[0], 3 * (h[0] * secant[1] + h[1] * secant[0]), 2 * secant[1]])
        return np.linalg.solve(a, b)
    lower = np.zeros(n)  # lower[i]: coefficient of s[i-1] in row i
    diagonal = np.zeros(n)
    upper = np.zeros(n)  # upper[i]: coefficient of s[i+1] in row i
    rhs = np.zeros((n, secant.shape[1]))
    lower[1:-1] = h[1:]
    diagonal[1:-1] = 2 * (h[:-1] + h[1:])
    upper[1:-1] = h[:-1]
    rhs[1:-1] = 3 * (h[1:, None] * secant[:-1] + h[:-1, None] * secant[1:])
    # not-a-knot: the third derivative is continuous across the second and last-but-one knots
    diagonal[0], upper[0] = h[1], h[0] + h[1]
    rhs[0] = ((h[0] + 2 * upper[0]) * h[1] * secant[0] + h[0] ** 2 * secant[1]) / upper[0]
    diagonal[-1], lower[-1] = h[-2], h[-1] + h[-2]
    rhs[-1] = (h[-1] ** 2 * secant[-2] + (2 * lower[-1] + h[-1]) * h[-2] * secant[-1]) / lower[-1]
    return _thomas(lower, diagonal, upper, rhs)


def _thomas(
    lower: np.ndarray, diagonal: np.ndarray, upper: np.ndarray, rhs: np.ndarray
) -> np.ndarray:
    """Tridiagonal solve without pivoting, all right-hand sides at once. Stable here: the
    interior rows are diagonally dominant, and eliminating the not-a-knot first row leaves the
    second a pivot of h0 + h1 > 0 (scipy pivots; the two agree to 1e-13 in the tests)."""
    n = len(diagonal)
    low, mid, up = lower.tolist(), diagonal.tolist(), upper.tolist()
    ratio, scale = [0.0] * n, [0.0] * n  # the elimination depends on the matrix alone
    scale[0] = 1.0 / mid[0]
    ratio[0] = up[0] * scale[0]
    for i in range(1, n):
        scale[i] = 1.0 / (mid[i] - low[i] * ratio[i - 1])
        ratio[i] = up[i] * scale[i]
    rows = rhs.tolist()
    width = rhs.shape[1]
    previous = [v * scale[0] for v in rows[0]]
    forward = [previous]
    for i in range(1, n):
        li, si, row = low[i], scale[i], rows[i]
        previous = [(row[k] - li * previous[k]) * si for k in range(width)]
        forward.append(previous)
    out = [forward[-1]]
    for i in range(n - 2, -1, -1):
        ri, row, after = ratio[i], forward[i], out[-1]
        out.append([row[k] - ri * after[k] for k in range(width)])
    return np.array(out[::-1])


class SplineTable:
    """Many CubicSplines evaluated in one pass: every sample names the spline it belongs to.

    The splines' knots and coefficients are put end to end; each spline's interval search is
    its own (one searchsorted per spline); the polynomials are evaluated in chunks of CHUNK
    samples (temporaries that stay in the cache), with the same arithmetic per sample as
    `CubicSpline.with_derivatives`, hence the same values.
    """

    CHUNK = 2048

    def __init__(self, splines: list[CubicSpline]):
        if not splines:
            raise ValueError("SplineTable: no splines")
        width = splines[0].c.shape[2]
        if any(spline.c.shape[2] != width for spline in splines):
            raise ValueError("SplineTable: the splines have different value sizes")
        self.splines = splines
        self.width = width
        self.x = np.concatenate([spline.x[:-1] for spline in splines])
        c3, c2, c1, c0 = np.concatenate([spline.c for spline in splines], axis=1)
        # Columns (value, interval): the arithmetic runs along samples, not along 6 joints.
        # 3 * c3 * t is (3 * c3) * t: the products are precomputed, the values unchanged.
        self.rates = np.concatenate([3 * c3, 2 * c2, c1, 6 * c3], axis=1).T.copy()
        self.values = np.concatenate([c3, c2, c1, c0], axis=1).T.copy()
        counts = [len(spline.x) - 1 for spline in splines]
        self.first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.intp)
        """Where each spline's intervals start in x and the coefficient columns."""

    def intervals(self, which: list[int], at: np.ndarray, counts: list[int]) -> np.ndarray:
        """Interval of every sample: `at` holds `counts[k]` samples on spline `which[k]`, end
        to end (each spline's own search; the clipping to its ends for all at once)."""
        local, start = [], 0
        for spline_index, count in zip(which, counts, strict=True):
            knots = self.splines[spline_index].x
            local.append(np.searchsorted(knots, at[start : start + count], side="right"))
            start += count
        if not local:
            return np.zeros(0, dtype=np.intp)
        last = np.array([len(self.splines[k].x) - 2 for k in which])
        rows = np.clip(np.concatenate(local) - 1, 0, np.repeat(last, counts))
        return rows + np.repeat(self.first[which], counts)

    def chunks(
        self, at: np.ndarray, rows: np.ndarray, values: bool = True
    ) -> Iterator[tuple[slice, np.ndarray | None, np.ndarray, np.ndarray]]:
        """(samples, values or None, first, second derivatives), each (width, m): one column
        per sample, chunk by chunk, at `at` on the intervals `rows` (from `intervals`)."""
        w = self.width
        for begin in range(0, len(at), self.CHUNK):
            part = slice(begin, begin + self.CHUNK)
            here = rows[part]
            t = at[part] - self.x[here]
            block = self.rates.take(here, axis=1)
            second = block[3 * w :]  # (a slice of this chunk's own copy: computed in place)
            second *= t
            second += block[w : 2 * w]
            first = block[:w]
            first *= t
            first += block[w : 2 * w]
            first *= t
            first += block[2 * w : 3 * w]
            value = None
            if values:
                c = self.values.take(here, axis=1)
                value = c[:w] * t
                value += c[w : 2 * w]
                value *= t
                value += c[2 * w : 3 * w]
                value *= t
                value += c[3 * w :]
            yield part, value, first, second
