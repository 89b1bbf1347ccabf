"""The block convolution that fits use agrees with the plain recursive filter it replaces."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from keymps.primitives.filters import BLOCK, FilterError, all_pole, block_convolve, fir
from keymps.primitives.system import _hold_exponential, discretize


def recursive(rows: np.ndarray, b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The reference: B(q) then 1 / A(q), one sample after another (LAPACK's banded solve)."""
    return all_pole(a, fir(b, rows))


def impulse_response(b: np.ndarray, a: np.ndarray, length: int) -> tuple[np.ndarray, np.ndarray]:
    unit = np.zeros(length)
    unit[0] = 1.0
    free = all_pole(a, unit)
    return fir(b, free), free


@settings(max_examples=60, deadline=None)
@given(
    length=st.integers(1, 700),
    count=st.integers(1, 8),
    block=st.integers(3, 60),
    steps=st.integers(10, 5000),
    seed=st.integers(0, 2**32 - 1),
)
def test_block_convolution_equals_the_recursive_filter(
    length: int, count: int, block: int, steps: int, seed: int
) -> None:
    """Any length (a whole number of blocks or not, shorter than one block), any block size,
    the DMP's own filters at any sample rate: the same outputs to rounding."""
    filters = discretize(1.0 / steps, 156.25, 25.0)
    rows = np.random.default_rng(seed).standard_normal((count, length))
    impulse, _ = impulse_response(filters.b_pos, filters.a, length + block + 2)
    expected = recursive(rows, filters.b_pos, filters.a)
    got = block_convolve(rows, impulse, filters.a, block=block)
    assert got.shape == rows.shape
    assert np.abs(got - expected).max() <= 1e-12 * max(1.0, np.abs(expected).max())


def test_block_convolution_with_distinct_poles() -> None:
    """Not only the critically damped DMP system: an underdamped pair of poles as well."""
    radius, angle = 0.97, 0.2
    a = np.array([1.0, -2 * radius * np.cos(angle), radius**2])
    b = np.array([0.3, -0.1, 0.05])
    rows = np.random.default_rng(1).standard_normal((5, 333))
    impulse, _ = impulse_response(b, a, 333 + BLOCK + 2)
    expected = recursive(rows, b, a)
    got = block_convolve(rows, impulse, a)
    assert np.abs(got - expected).max() <= 1e-12 * np.abs(expected).max()


def test_too_short_an_impulse_response_is_refused() -> None:
    filters = discretize(1e-3, 156.25, 25.0)
    impulse, _ = impulse_response(filters.b_pos, filters.a, BLOCK)
    with pytest.raises(FilterError, match="impulse response shorter"):
        block_convolve(np.ones((2, 100)), impulse, filters.a)


@pytest.mark.parametrize(
    "stiffness, damping", [(156.25, 25.0), (2500.0, 0.3), (1.0, 100.0), (0.0, 25.0)]
)
@pytest.mark.parametrize("samples", [2, 3, 9, 100, 1000, 100_000])
def test_hold_discretization_matches_the_matrix_exponential(
    stiffness: float, damping: float, samples: int
) -> None:
    """The plain-float scaling and squaring equals scipy's expm of the augmented matrix, for
    the DMP's gains and for under- and overdamped ones, from 2 to 100,000 samples."""
    from scipy.linalg import expm

    step = 1.0 / (samples - 1)
    augmented = np.zeros((4, 4))
    augmented[0, 1] = 1.0
    augmented[1] = [-stiffness, -damping, 1.0, 0.0]
    augmented[2, 3] = 1.0 / step
    expected = expm(augmented * step)[:2]
    (p00, p01, p10, p11), gamma1, gamma2 = _hold_exponential(step, stiffness, damping)
    got = np.array([[p00, p01, gamma1[0], gamma2[0]], [p10, p11, gamma1[1], gamma2[1]]])
    scale = np.abs(expected).max(axis=1, keepdims=True)
    assert (np.abs(got - expected) <= 1e-12 * scale).all()
