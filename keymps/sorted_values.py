"""Medians, percentiles and distinct values of plain arrays, NumPy's to the bit, without numpy.ma.

np.median, np.percentile and a bare np.unique (np.union1d calls it) ask numpy.ma whether their
input is a masked array, and the first such call in a process imports numpy.ma: 10-13 ms
of a run's start for nothing a run uses. These give NumPy's numbers bit for bit (the same
partition, the same mean of the middle values, the same interpolation in the input's own
precision; tests/test_sorted_values.py compares them on thousands of arrays) for plain arrays:
a NaN in a slice gives NaN, as NumPy's do.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def median(values: np.ndarray, axis: int | None = None) -> np.ndarray:
    """np.median(values, axis): the middle value, or the mean of the two middle values."""
    data = np.asarray(values)
    if axis is None:
        data, axis = data.reshape(-1), 0
    axis = axis % max(data.ndim, 1)
    count = data.shape[axis]
    if count == 0:
        return np.asarray(np.median(data, axis=axis))  # NumPy's own warning and NaN
    middle = [count // 2] if count % 2 else [count // 2 - 1, count // 2]
    part = np.partition(data, middle, axis=axis)
    taken = np.take(part, range(middle[0], middle[-1] + 1), axis=axis)
    result = np.mean(taken, axis=axis)
    if np.issubdtype(data.dtype, np.inexact):
        result = np.where(np.isnan(data).any(axis=axis), np.nan, result)
    return np.asarray(result)


def percentile(values: np.ndarray, q: float) -> float:
    """float(np.percentile(values, q)) of all values, NumPy's default 'linear' method, for
    floating-point values (computed in their own precision, as NumPy does)."""
    data = np.asarray(values).reshape(-1)
    count = len(data)
    if count == 0 or not 0 <= q <= 100 or not np.issubdtype(data.dtype, np.floating):
        return float(np.percentile(data, q))  # NumPy's own error, warning or integer rules
    if np.isnan(data).any():
        return math.nan
    virtual = float((count - 1) * np.true_divide(q, 100))
    below = min(math.floor(virtual), count - 1)
    above = min(below + 1, count - 1)
    part = np.partition(data, sorted({below, above}))
    low, high = part[below], part[above]
    gamma = virtual - math.floor(virtual)
    difference = high - low
    if gamma >= 0.5:  # NumPy's lerp, from the nearer end
        return float(high - difference * (1 - gamma))
    return float(low + difference * gamma)


def distinct(values: Any) -> np.ndarray:
    """np.unique(values) of integers, booleans or strings: the distinct values, sorted."""
    data = np.sort(np.asarray(values).reshape(-1))
    if len(data) == 0:
        return data
    return data[np.concatenate(([True], data[1:] != data[:-1]))]
