"""keymps.sorted_values: NumPy's median, percentile and unique, bit for bit, without numpy.ma."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from keymps.sorted_values import distinct, median, percentile

TASKS = Path(__file__).resolve().parents[1] / "tasks"


def _samples(rng: np.random.Generator) -> np.ndarray:
    """Arrays as a run makes them: sizes odd and even, ties, outliers, several scales."""
    size = int(rng.choice([1, 2, 3, 4, 5, 10, 11, 100, 101, 1000, 1001, 12_000]))
    kind = rng.integers(4)
    if kind == 0:
        return rng.normal(0, 10 ** float(rng.uniform(-6, 3)), size)
    if kind == 1:  # ties: a flat board's Lab distances
        return rng.integers(0, 5, size).astype(float) * 0.25
    if kind == 2:  # a few far outliers
        values = rng.exponential(1.0, size)
        values[: max(1, size // 50)] *= 1e4
        return values
    return rng.uniform(-1, 1, size).astype(np.float32)


def test_median_is_numpys_to_the_bit() -> None:
    rng = np.random.default_rng(11)
    for _ in range(2000):
        values = _samples(rng)
        assert median(values).tobytes() == np.asarray(np.median(values)).tobytes()


def test_median_along_an_axis_is_numpys_to_the_bit() -> None:
    rng = np.random.default_rng(12)
    for _ in range(300):
        rows, columns = (int(v) for v in rng.integers(1, 60, 2))
        values = rng.normal(size=(rows, columns)) * float(rng.uniform(0.01, 100))
        for axis in (0, 1, -1):
            assert median(values, axis).tobytes() == np.median(values, axis=axis).tobytes()


def test_percentile_is_numpys_to_the_bit() -> None:
    rng = np.random.default_rng(13)
    for _ in range(2000):
        values = _samples(rng)
        q = float(rng.choice([0, 25, 50, 75, 99.5, 100, rng.uniform(0, 100)]))
        assert percentile(values, q) == float(np.percentile(values, q)), (len(values), q)


def test_distinct_is_numpys_unique() -> None:
    rng = np.random.default_rng(14)
    for _ in range(500):
        size = int(rng.integers(0, 300))
        values = rng.integers(-5, int(rng.integers(1, 50)), size)
        for kind in (np.int64, np.intp, np.int32, np.uint8, bool):
            cast = values.astype(kind) if kind is not bool else values > 0
            got, want = distinct(cast), np.unique(cast)
            assert got.dtype == want.dtype and np.array_equal(got, want)
    words = np.array(["work", "travel", "work", "rest", "travel"])
    assert np.array_equal(distinct(words), np.unique(words))
    assert np.array_equal(distinct([[3, 1], [1, 2]]), [1, 2, 3])


def test_a_nan_gives_nan_as_numpy_does() -> None:
    values = np.array([1.0, np.nan, 3.0, 4.0])
    assert np.isnan(median(values)) and np.isnan(percentile(values, 50))
    grid = np.array([[1.0, 2.0], [np.nan, 5.0], [3.0, 4.0]])
    with np.errstate(invalid="ignore"):
        assert np.array_equal(median(grid, 0), np.median(grid, axis=0), equal_nan=True)
    assert np.array_equal(median(grid, 1), np.median(grid, axis=1), equal_nan=True)


def test_empty_input_and_a_bad_q_behave_as_numpy() -> None:
    with pytest.warns(RuntimeWarning):
        assert np.isnan(median(np.array([])))
    with pytest.raises(ValueError):
        percentile(np.array([1.0, 2.0]), 101)


@pytest.mark.parametrize("task", ["cake_icing.yaml", "object_cutting.yaml"])
def test_a_run_never_imports_numpy_ma(task: str) -> None:
    """The reason this module exists: a whole offline run (board detection, the design, the
    sim's marks and cut sweeps) without numpy.ma."""
    code = (
        "import sys, tempfile; from keymps import RunOptions, RunOverrides, run_task;"
        "d = tempfile.mkdtemp();"
        f"run_task({str(TASKS / task)!r}, options=RunOptions(rerun='off', quiet=True),"
        " overrides=RunOverrides(out=d + '/r', backend='offline', executor='sim'));"
        "print('numpy.ma' in sys.modules)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split()[-1] == "False"
