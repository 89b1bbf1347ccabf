"""The DMP transformation system, discretized exactly, and the least-squares fitting basis.

tau z' = K (g - y) - D z + u(t), tau y' = z with an input u that depends on time only is linear
in y: it is discretized exactly (matrix exponential, first-order hold on the input) and run as a
second-order IIR filter over all samples at once (keymps.primitives.filters). A fit needs the response
to every basis function; they are the columns of one regularized least-squares problem on
positions. Helpers of keymps.primitives.dmp; not a public API.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from keymps.errors import KeympsError
from keymps.primitives.filters import BLOCK, all_pole, block_convolve, fir

ALPHA_Z = 25.0
BETA_Z = ALPHA_Z / 4.0
ALPHA_S = 4.0
MAX_CACHED_GRIDS = 16


class DmpError(KeympsError):
    """A demonstration, a DMP parameter set or a rollout request is invalid."""


@dataclass(frozen=True)
class Filters:
    """IIR coefficients of the transformation system for one normalized step, zero initial state."""

    a: np.ndarray
    b_pos: np.ndarray
    b_vel: np.ndarray
    first_pos: np.ndarray
    """Impulse correction: output response to u[0] that the zero-history filter adds."""
    first_vel: np.ndarray

    @property
    def numerators(self) -> np.ndarray:
        """(4, 3): b_pos, first_pos, b_vel and first_vel (zero-padded), one per row."""
        return np.array(
            [self.b_pos, [*self.first_pos, 0.0], self.b_vel, [*self.first_vel, 0.0]], dtype=float
        )


@functools.lru_cache(maxsize=64)
def discretize(step: float, stiffness: float, damping: float) -> Filters:
    """First-order-hold discretization of p' = z, z' = u - K p - D z (normalized time)."""
    (p00, p01, p10, p11), (g1_0, g1_1), (g2_0, g2_1) = _hold_exponential(step, stiffness, damping)
    a = np.array([1.0, -(p00 + p11), p00 * p11 - p01 * p10])
    # x[n] = Phi x[n-1] + g_prev u[n-1] + g_now u[n]; C (I - Phi q^-1)^-1 G = (C G + c q^-1) /
    # (1 - tr q^-1 + det q^-2) for a 2 x 2 Phi, with c the "tail" below.
    now = (g2_0, g2_1)
    prev = (g1_0 - g2_0, g1_1 - g2_1)
    pos_tail_now, pos_tail_prev = (p01 * g[1] - p11 * g[0] for g in (now, prev))
    vel_tail_now, vel_tail_prev = (p10 * g[0] - p00 * g[1] for g in (now, prev))
    b_pos = np.array([now[0], pos_tail_now + prev[0], pos_tail_prev])
    b_vel = np.array([now[1], vel_tail_now + prev[1], vel_tail_prev])
    first_pos = np.array([now[0], pos_tail_now])
    first_vel = np.array([now[1], vel_tail_now])
    return Filters(a, b_pos, b_vel, first_pos, first_vel)


def _hold_exponential(
    step: float, stiffness: float, damping: float
) -> tuple[tuple[float, float, float, float], tuple[float, float], tuple[float, float]]:
    """Phi = e^(A h) (row-major) and the first-order-hold input vectors gamma1 = integral of
    e^(A s) b over [0, h] and gamma2 = the same weighted by (h - s) / h, for A = [[0, 1], [-K,
    -D]], b = [0, 1], h = step: the blocks of the exponential of [[A, b, 0], [0, 0, 1/h],
    [0, 0, 0]] h. Scaling and squaring of a Taylor series in plain floats (a 2 x 2 problem:
    array calls would cost more than the arithmetic)."""
    norm = step * max(abs(stiffness), 1.0 + abs(damping))
    squarings = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    h = step / 2.0**squarings
    x00, x01, x10, x11 = 0.0, h, -stiffness * h, -damping * h  # X = A h, norm <= 1/2
    # X^j / j! summed three ways: e^X, phi1(X) = sum X^j / (j+1)!, phi2(X) = sum X^j / (j+2)!
    t00, t01, t10, t11 = 1.0, 0.0, 0.0, 1.0
    e00, e01, e10, e11 = 1.0, 0.0, 0.0, 1.0
    f01, f11 = 0.0, 1.0  # phi1(X) b: the second column (b = [0, 1]); likewise s for phi2
    s01, s11 = 0.0, 0.5
    for j in range(1, 18):  # the next term would be below 1e-19 of the first
        t00, t01, t10, t11 = (
            (t00 * x00 + t01 * x10) / j,
            (t00 * x01 + t01 * x11) / j,
            (t10 * x00 + t11 * x10) / j,
            (t10 * x01 + t11 * x11) / j,
        )
        e00, e01, e10, e11 = e00 + t00, e01 + t01, e10 + t10, e11 + t11
        c1 = 1.0 / (j + 1)
        c2 = c1 / (j + 2)
        f01, f11 = f01 + t01 * c1, f11 + t11 * c1
        s01, s11 = s01 + t01 * c2, s11 + t11 * c2
    g1 = (h * f01, h * f11)
    g2 = (h * s01, h * s11)
    for _ in range(squarings):  # from step h to 2h: g1 += E g1, g2 = (g1 + g2 + E g2) / 2, E = E^2
        eg1 = (e00 * g1[0] + e01 * g1[1], e10 * g1[0] + e11 * g1[1])
        eg2 = (e00 * g2[0] + e01 * g2[1], e10 * g2[0] + e11 * g2[1])
        g2 = ((g1[0] + g2[0] + eg2[0]) / 2.0, (g1[1] + g2[1] + eg2[1]) / 2.0)
        g1 = (g1[0] + eg1[0], g1[1] + eg1[1])
        e00, e01, e10, e11 = (
            e00 * e00 + e01 * e10,
            e00 * e01 + e01 * e11,
            e10 * e00 + e11 * e10,
            e10 * e01 + e11 * e11,
        )
    return (e00, e01, e10, e11), g1, g2


def respond(filters: Filters, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalized-time position and velocity of the system driven by u (rows = samples), from
    zero initial state. One recursive pass serves both outputs (they share the poles)."""
    columns = np.ascontiguousarray(u.T)
    state = all_pole(filters.a, columns)
    impulse = np.zeros(columns.shape[-1])
    impulse[0] = 1.0
    free = all_pole(filters.a, impulse)
    pos = fir(filters.b_pos, state) - np.outer(columns[:, 0], fir(filters.first_pos, free))
    vel = fir(filters.b_vel, state) - np.outer(columns[:, 0], fir(filters.first_vel, free))
    return pos.T, vel.T


def basis_centers_widths(n_basis: int, alpha_s: float = ALPHA_S) -> tuple[np.ndarray, np.ndarray]:
    """Phase centres of Gaussians spread evenly in time, with widths equal in time."""
    spacing = 1.0 / max(n_basis - 1, 1)
    centers = np.exp(np.arange(n_basis) * (-alpha_s * spacing))
    widths = 1.0 / (2.0 * (spacing * alpha_s * centers) ** 2)
    return centers, widths


def phase_features(
    s: np.ndarray,
    n_basis: int,
    alpha_s: float,
    out: np.ndarray | None = None,
    scale: float = 1.0,
) -> np.ndarray:
    """psi_i(s) s / sum psi(s) for phases s, one row per basis function: (n_basis, N), times
    `scale`."""
    centers, _ = basis_centers_widths(n_basis, alpha_s)
    # Widths equal in time make h_i c_i^2 one constant, root^2, for every basis function:
    # -h_i (s - c_i)^2 = -(a_i s - root)^2 with a_i = root / c_i, expanded so that one small
    # matrix product gives every exponent (its rounding, 1e-14 near a centre, is harmless).
    spacing = 1.0 / max(n_basis - 1, 1)
    root = 1.0 / (math.sqrt(2.0) * spacing * alpha_s)
    slopes = root / centers
    left = np.empty((n_basis, 3))
    left[:, 0] = slopes * slopes
    left[:, 1] = slopes
    left[:, 2] = 1.0
    right = np.empty((3, len(s)))
    np.multiply(s, -s, out=right[0])
    np.multiply(s, 2.0 * root, out=right[1])
    right[2] = -root * root
    psi = np.matmul(left, right, out=out)
    # exp(-700) is 1e-304, nothing next to the nearest basis function's value (above
    # exp(-1/8)); larger arguments would only take exp's slow underflow path.
    np.maximum(psi, -700.0, out=psi)
    np.exp(psi, out=psi)
    psi *= s * scale / psi.sum(axis=0)
    return psi


_PIN = 1e3
"""Weight of the rows that pin the fitted end to the demonstrated goal, at rest."""


@dataclass(frozen=True)
class FitBasis:
    """Everything of a fit that depends only on the sample times (cached for uniform grids)."""

    weighted_design: np.ndarray
    """(n_basis, T): position response of each basis function at the samples, times each
    sample's weight."""
    end_position: np.ndarray
    """(n_basis,) position responses at the last sample."""
    end_velocity: np.ndarray
    goal_position: np.ndarray
    """(T,) response to a unit goal offset (the goal and Hoffmann terms)."""
    goal_end_velocity: float
    factor: tuple[np.ndarray, bool]
    """Cholesky factor of the regularized normal equations."""

    def solve(self, target: np.ndarray, end_velocity_target: np.ndarray) -> np.ndarray:
        """Weights for position targets (T, 3) and the wanted end velocity response (3,)."""
        from scipy.linalg.lapack import dpotrs

        right = self.weighted_design @ target
        right += _PIN**2 * np.outer(self.end_position, target[-1])
        right += _PIN**2 * np.outer(self.end_velocity, end_velocity_target)
        weights, info = dpotrs(self.factor[0], right, lower=0)
        if info != 0:  # pragma: no cover - only for invalid arguments
            raise DmpError(f"internal error: Cholesky solve failed (info {info})")
        return np.asarray(weights)


_FIT_BASES: dict[tuple[int, int, float], FitBasis] = {}


def fit_basis(phase_time: np.ndarray, n_basis: int, regularization: float) -> FitBasis:
    """The least-squares basis for samples at normalized times phase_time (0 ... 1).

    Args:
        phase_time: (T,) increasing sample times, normalized to 0 ... 1.
        n_basis: Basis functions per axis.
        regularization: Ridge weight, relative to the mean diagonal of the normal equations.

    Returns:
        The basis; uniform samples share one cached basis per (T, n_basis, regularization).
    """
    steps = np.diff(phase_time)
    uniform = bool(np.abs(steps - steps[0]).max() <= 1e-6 * steps[0])
    key = (len(phase_time), n_basis, regularization)
    if uniform and key in _FIT_BASES:
        return _FIT_BASES[key]
    num = len(phase_time) if uniform else max(len(phase_time), 1000)
    grid, pos, vel_end = _uniform_responses(num, n_basis)
    if not uniform:
        pos = _interp_rows(grid, pos.T, phase_time).T
        # Samples weighted by the time each stands for, so dense stretches do not dominate.
        sample_weight = np.gradient(phase_time) * len(phase_time)
        return _factored(pos, vel_end, n_basis, regularization, sample_weight)
    basis = _factored(pos, vel_end, n_basis, regularization, None)
    if len(_FIT_BASES) >= MAX_CACHED_GRIDS:
        _FIT_BASES.pop(next(iter(_FIT_BASES)))
    _FIT_BASES[key] = basis
    return basis


def _uniform_responses(num: int, n_basis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The system's response to each basis function, then to a unit goal offset, from rest on
    `num` uniform samples of 0 ... 1: the grid (num,), positions (n_basis + 1, num) and the
    velocities at the last sample (n_basis + 1,)."""
    stiffness, damping = ALPHA_Z * BETA_Z, ALPHA_Z
    inputs, grid = _basis_inputs(num, n_basis, stiffness)
    filters = discretize(float(grid[1]), stiffness, damping)
    position, correction, velocity, velocity_correction = _impulse_responses(filters, num)
    # Only the last velocity is needed: one dot product with the reversed impulse response.
    first = inputs[:, 0].copy()
    vel_end = inputs[:, :num] @ velocity[num - 1 :: -1].copy()
    vel_end -= first * velocity_correction[num - 1]
    pos = block_convolve(inputs, position, filters.a, overwrite=True)[:, :num]
    # Undo the filter's response to u[0] arriving with zero history (x[0] must be 0); only the
    # first few basis functions (the leading rows) are active at t = 0.
    magnitude = np.abs(first)
    active = int(np.flatnonzero(magnitude > 1e-14 * magnitude.max())[-1]) + 1
    pos[:active] -= np.outer(first[:active], correction[:num])
    return grid, pos, vel_end


def _basis_inputs(num: int, n_basis: int, stiffness: float) -> tuple[np.ndarray, np.ndarray]:
    """The inputs as rows, one per basis function, then the goal term ((n_basis + 1, P), P
    the samples zero-padded to whole blocks, so that block_convolve reads them in place), and
    the times of the `num` samples (num,)."""
    padded = -(-num // BLOCK) * BLOCK
    times = np.arange(padded) * (1.0 / (num - 1))
    s = np.exp(-ALPHA_S * times)
    # A fresh array: the block convolution turns it into the responses, which the cache keeps.
    inputs = np.empty((n_basis + 1, padded))
    phase_features(s, n_basis, ALPHA_S, out=inputs[:n_basis], scale=stiffness)
    np.multiply(stiffness, 1.0 - s, out=inputs[n_basis])
    inputs[:, num:] = 0.0
    return inputs, times[:num]


def _impulse_responses(filters: Filters, num: int) -> np.ndarray:
    """(4, num + BLOCK + 2): the numerators for positions and velocities and the corrections
    for u[0] (Filters.numerators' rows) applied to the all-pole impulse response, in one
    product with its lagged copies (block_convolve needs BLOCK + 2 samples at least)."""
    impulse = np.zeros(num + BLOCK + 2)
    impulse[0] = 1.0
    free = all_pole(filters.a, impulse)
    lagged = np.zeros((3, len(free)))
    lagged[0] = free
    lagged[1, 1:] = free[:-1]
    lagged[2, 2:] = free[:-2]
    return filters.numerators @ lagged


def _factored(
    pos: np.ndarray,
    vel_end: np.ndarray,
    n_basis: int,
    regularization: float,
    sample_weight: np.ndarray | None,
) -> FitBasis:
    """The basis from the responses at the samples (`_uniform_responses`' pos, on the fit's
    samples) and at the end, each sample weighted by `sample_weight` (None: all alike)."""
    from scipy.linalg.blas import dsyrk
    from scipy.linalg.lapack import dpotrf

    design = pos[:n_basis]
    if sample_weight is None:
        weighted, root_weighted = design, design
    else:
        weighted, root_weighted = design * sample_weight, design * np.sqrt(sample_weight)
    # Upper triangle of design W design^T; the transpose is Fortran-ordered, so BLAS reads the
    # rows in place instead of f2py copying them.
    gram = dsyrk(1.0, np.ascontiguousarray(root_weighted).T, trans=1)
    ends = np.stack([design[:, -1], vel_end[:n_basis]])
    # The ridge term is relative to the samples' own normal equations: scaled by a trace that
    # included the pin rows (10^6 times heavier), it smoothed the fit 10x beyond the data.
    gram.flat[:: n_basis + 1] += regularization * float(np.trace(gram)) / n_basis
    gram += _PIN**2 * (ends.T @ ends)
    factor, info = dpotrf(gram, lower=0, clean=0, overwrite_a=1)
    if info != 0:  # pragma: no cover - regularized normal equations are positive definite
        raise DmpError(f"internal error: Cholesky factorization failed (info {info})")
    return FitBasis(
        weighted_design=weighted,
        end_position=ends[0],
        end_velocity=ends[1],
        goal_position=pos[n_basis],
        goal_end_velocity=float(vel_end[n_basis]),
        factor=(factor, False),
    )


def clear_caches() -> None:
    """Forget cached fit bases and discretizations (for cold-start timing)."""
    _FIT_BASES.clear()
    discretize.cache_clear()


def _interp_rows(grid: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Linear interpolation of every column of values (sampled on grid) at the times `at`."""
    index = np.clip(np.searchsorted(grid, at, side="right") - 1, 0, len(grid) - 2)
    frac = ((at - grid[index]) / (grid[index + 1] - grid[index]))[:, None]
    return values[index] * (1.0 - frac) + values[index + 1] * frac
