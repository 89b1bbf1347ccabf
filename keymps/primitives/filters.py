"""Linear time-invariant filters along the rows of an array, for the DMP transformation system.

Two ways to run a filter B(q) / A(q) with a monic second-order A and zero history:

- `fir` then `all_pole`: the two halves, the recursion solved block after block in numpy (a
  few rows: rollouts, on every run's path, which therefore never imports scipy);
- `block_convolve`: the whole filter for many rows at once (a fit's 51 basis responses). The
  samples are cut into blocks; within a block the output is a small Toeplitz product, and what
  earlier blocks contribute is carried by two numbers per block (an impulse response of a
  second-order system obeys a two-term recursion, so two of its values fix all later ones).
  One matrix product does almost all of the work: for 51 rows of 1000 samples it takes about
  0.2 ms against 0.4 ms for the recursive pair, and agrees with it to 1e-13.

Helpers of keymps.primitives.system; not a public API.
"""

from __future__ import annotations

import functools
import math
import threading

import numpy as np

from keymps.errors import KeympsError

BLOCK = 25
"""Samples per block: small enough that the Toeplitz products waste little, large enough that
the products stay efficient and the blocks few."""


class FilterError(KeympsError):
    """An internal filtering step failed (never expected for valid coefficients)."""


def all_pole(a: np.ndarray, x: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """1 / A(q) along the last axis with zero history, for monic second-order A: the recursion
    y[n] = x[n] - a1 y[n-1] - a2 y[n-2], solved in blocks of BLOCK samples without scipy (a
    run's rollouts would otherwise pay scipy.linalg's import, a third of a second).

    Within a block the output is the input times the recursion's impulse-response Toeplitz
    matrix (one matrix product for all blocks), plus what the two last outputs of the previous
    block bring: those two carries follow a 2 x 2 recursion from block to block, the only loop.
    `overwrite` is accepted for the callers' sake (the result is always a new array)."""
    del overwrite
    columns = np.asarray(x, dtype=float)
    columns = columns.reshape(1, -1) if columns.ndim == 1 else columns
    count, length = columns.shape
    if length == 0:
        return np.zeros(np.shape(x))
    block = min(BLOCK, length)
    blocks = -(-length // block)
    padded = np.zeros((count, blocks * block))
    padded[:, :length] = columns
    impulse, ones, twos = _all_pole_responses(float(a[1]), float(a[2]), block)
    shifted = np.zeros(2 * block - 1)
    shifted[block - 1 :] = impulse
    toeplitz = shifted[_toeplitz_index(block)]  # toeplitz[j, i] = impulse[i - j], upper
    own = (padded.reshape(count * blocks, block) @ toeplitz).reshape(count, blocks, block)
    # carries: block k's last two outputs, (y[-2], y[-1]), from its own part and block k - 1's
    entering = np.zeros((count, blocks, 2))
    previous = np.zeros((count, 2))
    for k in range(1, blocks):
        last = own[:, k - 1, -2:] + previous[:, :1] * twos[-2:] + previous[:, 1:] * ones[-2:]
        entering[:, k] = previous = last
    out = own + entering[:, :, :1] * twos + entering[:, :, 1:] * ones
    return out.reshape(count, blocks * block)[:, :length].reshape(np.shape(x))


@functools.lru_cache(maxsize=32)
def _all_pole_responses(a1: float, a2: float, block: int) -> tuple[np.ndarray, ...]:
    """The recursion's impulse response over one block, and its free responses to a previous
    output of 1 one sample back (`ones`) and two samples back (`twos`)."""

    def run(first: float, second: float, drive: float) -> np.ndarray:
        out, y1, y2 = [], first, second  # y1 = y[-1], y2 = y[-2]
        for n in range(block):
            y = (drive if n == 0 else 0.0) - a1 * y1 - a2 * y2
            out.append(y)
            y1, y2 = y, y1
        return np.array(out)

    responses = (run(0.0, 0.0, 1.0), run(1.0, 0.0, 0.0), run(0.0, 1.0, 0.0))
    for response in responses:
        response.flags.writeable = False
    return responses


def fir(b: np.ndarray, v: np.ndarray) -> np.ndarray:
    """B(q) along the last axis, zero history (the moving-average half of the filter)."""
    out = np.multiply(v, b[0])
    for lag in range(1, len(b)):
        out[..., lag:] += b[lag] * v[..., :-lag]
    return out


def block_convolve(
    rows: np.ndarray,
    impulse: np.ndarray,
    a: np.ndarray,
    block: int = BLOCK,
    overwrite: bool = False,
) -> np.ndarray:
    """y[n] = sum over m <= n of impulse[n - m] rows[m], along the last axis of a 2D array.

    `impulse` (at least `block` + 2 samples) must obey impulse[n] = -a1 impulse[n-1]
    - a2 impulse[n-2] from n = 3 on, as the impulse response of B(q) / A(q) with B of degree at
    most 2 does. Then, for d >= 1, impulse[d + i] = alpha[i] impulse[d] + beta[i] impulse[d + 1]
    with alpha, beta the recursion's two fundamental solutions, so what block k receives from
    all earlier inputs is fixed by two carries: the outputs at its first two samples that the
    earlier blocks alone produce. With `overwrite`, C-ordered rows of whole blocks are replaced
    by the result (no copy, half the memory traffic).
    """
    from scipy.linalg.blas import dgemm, dtrmm

    count, length = rows.shape
    if len(impulse) < block + 2:
        raise FilterError(f"internal error: impulse response shorter than {block + 2} samples")
    blocks = -(-length // block)
    if overwrite and blocks * block == length and rows.flags.c_contiguous:
        work = rows
    else:
        work = np.zeros((count, blocks * block))
        work[:, :length] = rows
    samples = work.reshape(count * blocks, block)  # one block per row
    alpha, beta = _fundamental_solutions(a, block + 2)
    # What each block alone passes on: its response at the next block's first two samples.
    passed_on = np.empty((block, 2))
    passed_on[:, 0] = impulse[block:0:-1]
    passed_on[:, 1] = impulse[block + 1 : 1 : -1]
    own = (samples @ passed_on).reshape(count, 2 * blocks)
    carries = _accumulate_carries(own, alpha, beta, block)
    entering = np.zeros((count, blocks, 2))  # block k receives what leaves block k - 1
    entering[:, 1:] = carries.reshape(count, blocks, 2)[:, :-1]
    # Within each block, in place: samples := samples @ toeplitz (upper triangular,
    # toeplitz[j, i] = impulse[i - j]), as BLAS's triangular product on the transposed view.
    shifted = np.zeros(2 * block - 1)
    shifted[block - 1 :] = impulse[:block]
    toeplitz = shifted[_toeplitz_index(block)]  # zero below the diagonal: shifted starts with zeros
    dtrmm(1.0, toeplitz, samples.T, side=0, lower=0, trans_a=1, overwrite_b=1)
    # ... plus what the carries bring, alpha[i] c0 + beta[i] c1, accumulated in place.
    spread = np.array([alpha[:block], beta[:block]])
    dgemm(1.0, spread, entering.reshape(-1, 2).T, 1.0, samples.T, trans_a=1, overwrite_c=1)
    return work if blocks * block == length else work[:, :length]


@functools.lru_cache(maxsize=8)
def _toeplitz_index(block: int) -> np.ndarray:
    """Where kernel[j, i] sits in [0] * (block - 1) + impulse[:block]: block - 1 + i - j."""
    offsets = np.arange(block)
    return block - 1 + offsets[None, :] - offsets[:, None]


def _fundamental_solutions(a: np.ndarray, length: int) -> tuple[np.ndarray, np.ndarray]:
    """The first `length` values of alpha and beta, the solutions of x[n] = -a1 x[n-1] - a2
    x[n-2] that start (1, 0) and (0, 1) (a few dozen values: plain floats)."""
    a1, a2 = float(a[1]), float(a[2])
    alpha, beta = [1.0, 0.0], [0.0, 1.0]
    for _ in range(length - 2):
        alpha.append(-a1 * alpha[-1] - a2 * alpha[-2])
        beta.append(-a1 * beta[-1] - a2 * beta[-2])
    return np.array(alpha), np.array(beta)


def _accumulate_carries(
    own: np.ndarray, alpha: np.ndarray, beta: np.ndarray, block: int
) -> np.ndarray:
    """Carries leaving every block, c[k+1] = F c[k] + own[k] with c[0] = 0, for rows of
    interleaved pairs (count, 2 blocks); F advances a pair of carries by one block.

    The recursion is a unit lower-triangular system with three subdiagonals (in the interleaved
    order), solved by LAPACK's banded solver: first-order in the pair, so as well conditioned as
    the filter itself however many blocks there are."""
    from scipy.linalg.lapack import dtbtrs

    f00, f01, f10, f11 = alpha[block], beta[block], alpha[block + 1], beta[block + 1]
    size = own.shape[1]
    band = np.zeros((4, size))
    band[0] = 1.0
    band[1, 1::2] = -f01  # c0[k+1] <- c1[k]
    band[2, 0::2] = -f00  # c0[k+1] <- c0[k]
    band[2, 1::2] = -f11  # c1[k+1] <- c1[k]
    band[3, 0::2] = -f10  # c1[k+1] <- c0[k]
    solution, info = dtbtrs(band, own.T, uplo="L", diag="U")
    if info != 0:  # pragma: no cover - a unit diagonal cannot be singular
        raise FilterError(f"internal error: banded solve failed (info {info})")
    return np.asarray(solution.T)


_WORKSPACE = threading.local()
_WORKSPACE_MAX_ELEMENTS = 1 << 19


def workspace(name: str, shape: tuple[int, ...]) -> np.ndarray:
    """A per-thread scratch array (contents undefined), reused across calls: large temporaries
    would otherwise be fresh memory mappings, and page faults, on every call. Arrays above
    4 MB are not kept."""
    if math.prod(shape) > _WORKSPACE_MAX_ELEMENTS:
        return np.empty(shape)
    pool: dict[str, np.ndarray] = _WORKSPACE.__dict__.setdefault("pool", {})
    array = pool.get(name)
    if array is None or array.shape != shape:
        array = pool[name] = np.empty(shape)
    return array
