"""The DMP transformation system, discretized exactly, and the least-squares fitting basis.

tau z' = K (g - y) - D z + u(t), tau y' = z with an input u that depends on time only is linear
in y: it is discretized exactly (matrix exponential, first-order hold on the input) and run as a
second-order IIR filter over all samples at once. The filter's recursion is solved as a banded
lower-triangular system (LAPACK dtbtrs), which is the all-pole pass of scipy.signal.lfilter
without the second it takes to import scipy.signal. Helpers of keymps.dmp; not a public API.
"""

from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass

import numpy as np

from keymps.errors import KeympsError

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


@functools.lru_cache(maxsize=64)
def discretize(step: float, stiffness: float, damping: float) -> Filters:
    """First-order-hold discretization of p' = z, z' = u - K p - D z (normalized time)."""
    block = np.zeros((4, 4))
    block[0, 1] = 1.0
    block[1, 0] = -stiffness
    block[1, 1] = -damping
    block[1, 2] = 1.0
    block[2, 3] = 1.0 / step
    big = _expm(block * step)
    phi = big[:2, :2]
    gamma1, gamma2 = big[:2, 2], big[:2, 3]
    g_prev, g_now = gamma1 - gamma2, gamma2
    a = np.array([1.0, -np.trace(phi), np.linalg.det(phi)])

    def numerator(row: int) -> tuple[np.ndarray, np.ndarray]:
        # C (I - Phi q^-1)^-1 G = (C G + c q^-1) / (1 - tr q^-1 + det q^-2) for a 2x2 Phi.
        def tail(g: np.ndarray) -> float:
            if row == 0:
                return float(phi[0, 1] * g[1] - phi[1, 1] * g[0])
            return float(phi[1, 0] * g[0] - phi[0, 0] * g[1])

        b = np.array([g_now[row], tail(g_now) + g_prev[row], tail(g_prev)])
        first = np.array([g_now[row], tail(g_now)])
        return b, first

    b_pos, first_pos = numerator(0)
    b_vel, first_vel = numerator(1)
    return Filters(a, b_pos, b_vel, first_pos, first_vel)


def _expm(matrix: np.ndarray) -> np.ndarray:
    """Matrix exponential of a tiny matrix: scaling and squaring with an order-18 Taylor series
    (accurate to rounding for norms up to 0.5 after scaling; no LAPACK call, no thread start-up).
    """
    norm = float(np.abs(matrix).sum(axis=0).max())
    squarings = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    scaled = matrix / 2.0**squarings
    result = np.eye(len(matrix))
    term = np.eye(len(matrix))
    for order in range(1, 19):
        term = term @ scaled / order
        result = result + term
    for _ in range(squarings):
        result = result @ result
    return result


def _all_pole(a: np.ndarray, x: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """1 / A(q) along the last axis with zero history, for monic second-order A: the recursion
    y[n] = x[n] - a1 y[n-1] - a2 y[n-2] is a unit lower-triangular banded system."""
    from scipy.linalg.lapack import dtbtrs

    columns = x.reshape(1, -1) if x.ndim == 1 else x
    length = columns.shape[-1]
    band = np.empty((3, length))
    band[0] = 1.0
    band[1] = a[1]
    band[2] = a[2]
    # x.T of a C-ordered (m, N) array is a Fortran-ordered (N, m) right-hand side: no copy.
    solution, info = dtbtrs(band, columns.T, uplo="L", diag="U", overwrite_b=int(overwrite))
    if info != 0:  # pragma: no cover - a unit diagonal cannot be singular
        raise DmpError(f"internal error: banded solve failed (info {info})")
    return np.asarray(solution.T).reshape(x.shape)


def _fir(
    b: np.ndarray, v: np.ndarray, out: np.ndarray | None = None, scratch: np.ndarray | None = None
) -> np.ndarray:
    """B(q) along the last axis, zero history (the moving-average half of the filter)."""
    out = np.multiply(v, b[0], out=out)
    scratch = np.empty_like(v) if scratch is None else scratch
    for lag in range(1, len(b)):
        np.multiply(v[..., :-lag], b[lag], out=scratch[..., lag:])
        out[..., lag:] += scratch[..., lag:]
    return out


_WORKSPACE = threading.local()


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


_WORKSPACE_MAX_ELEMENTS = 1 << 19


def respond(filters: Filters, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalized-time position and velocity of the system driven by u (rows = samples), from
    zero initial state. One recursive pass serves both outputs (they share the poles)."""
    columns = np.ascontiguousarray(u.T)
    state = _all_pole(filters.a, columns)
    impulse = np.zeros(columns.shape[-1])
    impulse[0] = 1.0
    free = _all_pole(filters.a, impulse)
    pos = _fir(filters.b_pos, state) - np.outer(columns[:, 0], _fir(filters.first_pos, free))
    vel = _fir(filters.b_vel, state) - np.outer(columns[:, 0], _fir(filters.first_vel, free))
    return pos.T, vel.T


def basis_centers_widths(n_basis: int, alpha_s: float = ALPHA_S) -> tuple[np.ndarray, np.ndarray]:
    """Phase centres of Gaussians spread evenly in time, with widths equal in time."""
    times = np.linspace(0.0, 1.0, n_basis)
    centers = np.exp(-alpha_s * times)
    spacing = 1.0 / max(n_basis - 1, 1)
    widths = 1.0 / (2.0 * (spacing * alpha_s * centers) ** 2)
    return centers, widths


def phase_features(
    s: np.ndarray, n_basis: int, alpha_s: float, out: np.ndarray | None = None
) -> np.ndarray:
    """psi_i(s) s / sum psi(s) for phases s, one row per basis function: (n_basis, N)."""
    centers, widths = basis_centers_widths(n_basis, alpha_s)
    psi = np.subtract(centers[:, None], s[None, :], out=out)
    np.square(psi, out=psi)
    psi *= -widths[:, None]
    np.exp(psi, out=psi)
    psi *= s / psi.sum(axis=0)
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
        from scipy.linalg import cho_solve

        right = self.weighted_design @ target
        right += _PIN**2 * np.outer(self.end_position, target[-1])
        right += _PIN**2 * np.outer(self.end_velocity, end_velocity_target)
        return np.asarray(cho_solve(self.factor, right, check_finite=False))


_FIT_BASES: dict[tuple[int, int, float], FitBasis] = {}


def fit_basis(phase_time: np.ndarray, n_basis: int, regularization: float) -> FitBasis:
    """The least-squares basis for samples at normalized times phase_time (0 ... 1)."""
    from scipy.linalg import cho_factor
    from scipy.linalg.blas import dsyrk

    steps = np.diff(phase_time)
    uniform = bool(np.abs(steps - steps[0]).max() <= 1e-6 * steps[0])
    key = (len(phase_time), n_basis, regularization)
    if uniform and key in _FIT_BASES:
        return _FIT_BASES[key]
    stiffness, damping = ALPHA_Z * BETA_Z, ALPHA_Z
    num = len(phase_time) if uniform else max(len(phase_time), 1000)
    grid = np.linspace(0.0, 1.0, num)
    s = np.exp(-ALPHA_S * grid)
    # Inputs as rows (one per basis function, then the goal term): the filters run along rows.
    inputs = workspace("inputs", (n_basis + 1, num))
    phase_features(s, n_basis, ALPHA_S, out=inputs[:n_basis])
    inputs[:n_basis] *= stiffness
    np.multiply(stiffness, 1.0 - s, out=inputs[n_basis])
    filters = discretize(float(grid[1]), stiffness, damping)
    pos = _fir(filters.b_pos, inputs, np.empty_like(inputs), workspace("fir", inputs.shape))
    pos = _all_pole(filters.a, pos, overwrite=True)
    impulse = np.zeros(num)
    impulse[0] = 1.0
    free = _all_pole(filters.a, impulse)
    # Undo the filter's response to u[0] arriving with zero history (x[0] must be 0); only the
    # first few basis functions are active at t = 0.
    active = np.flatnonzero(np.abs(inputs[:, 0]) > 1e-14 * np.abs(inputs[:, 0]).max())
    pos[active] -= np.outer(inputs[active, 0], _fir(filters.first_pos, free))
    # Only the last velocity is needed: one dot product with the reversed impulse response.
    vel_end = inputs @ _fir(filters.b_vel, free)[::-1]
    vel_end -= inputs[:, 0] * _fir(filters.first_vel, free)[-1]
    if not uniform:
        pos = _interp_rows(grid, pos.T, phase_time).T
    design = pos[:n_basis]
    if uniform:
        weighted, root_weighted = design, design
    else:
        # Samples weighted by the time each stands for, so dense stretches do not dominate.
        sample_weight = np.gradient(phase_time) * len(phase_time)
        weighted, root_weighted = design * sample_weight, design * np.sqrt(sample_weight)
    gram = dsyrk(1.0, root_weighted)  # upper triangle of design W design^T
    gram += _PIN**2 * np.outer(design[:, -1], design[:, -1])
    gram += _PIN**2 * np.outer(vel_end[:n_basis], vel_end[:n_basis])
    gram.flat[:: n_basis + 1] += regularization * float(np.trace(gram)) / n_basis
    basis = FitBasis(
        weighted_design=weighted,
        end_position=design[:, -1].copy(),
        end_velocity=vel_end[:n_basis].copy(),
        goal_position=pos[n_basis],
        goal_end_velocity=float(vel_end[n_basis]),
        factor=cho_factor(gram, lower=False, check_finite=False),
    )
    if uniform:
        if len(_FIT_BASES) >= MAX_CACHED_GRIDS:
            _FIT_BASES.pop(next(iter(_FIT_BASES)))
        _FIT_BASES[key] = basis
    return basis


def clear_caches() -> None:
    """Forget cached fit bases and discretizations (for cold-start timing)."""
    _FIT_BASES.clear()
    discretize.cache_clear()


def _interp_rows(grid: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Linear interpolation of every column of values (sampled on grid) at the times `at`."""
    index = np.clip(np.searchsorted(grid, at, side="right") - 1, 0, len(grid) - 2)
    frac = ((at - grid[index]) / (grid[index + 1] - grid[index]))[:, None]
    return values[index] * (1.0 - frac) + values[index + 1] * frac
