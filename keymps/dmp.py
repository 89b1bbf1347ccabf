"""Discrete DMPs in 3D: fit from one demonstration, roll out, re-target exactly.

Formulation (Hoffmann/Pastor 2009, isotropic gains, one linear map S on the forcing term):

    tau z' = K (g - y) - D z - K (g - y0) s + K S f(s),   tau y' = z,   tau s' = -alpha_s s
    f(s) = sum_i w_i psi_i(s) s / sum_i psi_i(s),         psi_i(s) = exp(-h_i (s - c_i)^2)

with K = alpha_z beta_z and D = alpha_z on every axis. S satisfies S (g_d - y0_d) = g - y0, so
the system is linear in y - y0 and every re-targeted rollout is exactly
y(t) = y0 + S (y_fit(t) - y0_d), where y_fit is the rollout for the demonstration's own start
and goal. The transformation system is discretized exactly (matrix exponential, first-order hold
on the input) and run as a second-order IIR filter over all samples at once: the recursion is
solved as a banded lower-triangular system (LAPACK dtbtrs), which is the all-pole pass of
scipy.signal.lfilter without the second it takes to import scipy.signal.
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from keymps.errors import KeympsError

RetargetMode = Literal["similarity", "axial", "translate"]
RETARGET_MODES: tuple[str, ...] = ("similarity", "axial", "translate")

ALPHA_Z = 25.0
BETA_Z = ALPHA_Z / 4.0
ALPHA_S = 4.0
ZERO_LENGTH_M = 1e-9
"""Segments and demonstrations shorter than this are treated as zero-length (dots)."""
_MAX_CACHED_GRIDS = 16


class DmpError(KeympsError):
    """A demonstration, a DMP parameter set or a rollout request is invalid."""


@dataclass(frozen=True)
class Rollout:
    """A sampled DMP trajectory: positions, velocities and accelerations in metres and seconds."""

    t: np.ndarray
    """(num,) seconds from the start of the primitive."""
    y: np.ndarray
    """(num, 3) positions."""
    yd: np.ndarray
    """(num, 3) velocities."""
    ydd: np.ndarray
    """(num, 3) accelerations."""
    transform: np.ndarray = field(default_factory=lambda: np.eye(3))
    """The 3x3 map S applied to the demonstration (S (g_d - y0_d) = reached goal - start)."""

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.y, axis=0), axis=1).sum())


# --------------------------------------------------------------------------- re-targeting maps


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Minimal rotation taking unit vector a to unit vector b (pi about the most vertical axis
    perpendicular to a when they are opposite), accurate to rounding in every direction."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    cos = a0 * b0 + a1 * b1 + a2 * b2
    k0, k1, k2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    sin = math.sqrt(k0 * k0 + k1 * k1 + k2 * k2)
    if cos >= 0.0:  # I + [k]x + [k]x^2 / (1 + cos), k = a x b: exact near parallel vectors
        skew = np.array([[0.0, -k2, k1], [k2, 0.0, -k0], [-k1, k0, 0.0]])
        return np.eye(3) + skew + (skew @ skew) / (1.0 + cos)
    if sin > 1e-3:  # Rodrigues with the unit axis: error ~ rounding / sin
        skew = np.array([[0.0, -k2, k1], [k2, 0.0, -k0], [-k1, k0, 0.0]]) / sin
        return np.eye(3) + sin * skew + (1.0 - cos) * (skew @ skew)
    # (Nearly) opposite: half a turn about the most vertical axis perpendicular to a, then the
    # tiny rest of the way.
    axis = np.array([-a2 * a0, -a2 * a1, 1.0 - a2 * a2])  # world z minus its part along a
    if np.linalg.norm(axis) < 1e-6:
        axis = np.array([1.0 - a0 * a0, -a0 * a1, -a0 * a2])  # a is vertical: turn about x
    axis = axis / np.linalg.norm(axis)
    half_turn = 2.0 * np.outer(axis, axis) - np.eye(3)
    return _rotation_between(half_turn @ np.asarray(a, dtype=float), b) @ half_turn


def _rotation_about_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def heading_rotation(
    demo_dir: np.ndarray, target_dir: np.ndarray, heading: float | None = None
) -> np.ndarray:
    """Rotation taking unit vector demo_dir to target_dir: first about world z (heading), then a
    tilt in the vertical plane. Horizontal stays horizontal and "down" stays down; it equals the
    minimal rotation whenever either vector is vertical or both are horizontal. For a vertical
    target, `heading` (radians about z), when given, is where the demo's heading turns to."""
    horizontal = 1e-9
    if math.hypot(demo_dir[0], demo_dir[1]) < horizontal:
        return _rotation_between(demo_dir, target_dir)
    if math.hypot(target_dir[0], target_dir[1]) < horizontal:
        if heading is None:
            return _rotation_between(demo_dir, target_dir)
        turn = _rotation_about_z(heading - math.atan2(demo_dir[1], demo_dir[0]))
        return _rotation_between(turn @ demo_dir, target_dir) @ turn
    yaw = math.atan2(target_dir[1], target_dir[0]) - math.atan2(demo_dir[1], demo_dir[0])
    turn = _rotation_about_z(yaw)
    return _rotation_between(turn @ demo_dir, target_dir) @ turn


def retarget_map(
    demo_delta: np.ndarray,
    delta: np.ndarray,
    mode: str = "similarity",
    heading: float | None = None,
) -> np.ndarray:
    """The 3x3 map S applied to the demonstration so that S demo_delta = delta (when possible).

    similarity: |delta|/|demo_delta| times the heading rotation; axial: the heading rotation
    after stretching only along demo_delta (a zero-length delta collapses the demo's travel along
    its own direction and keeps the rest: a dot); translate: identity. Zero-length demos, and
    zero-length deltas outside axial mode, use the identity (the demo is replayed translated).
    `heading` orients the demo about z when delta is vertical (e.g. the blade's current yaw).
    """
    demo_delta = np.asarray(demo_delta, dtype=float)
    delta = np.asarray(delta, dtype=float)
    if mode not in RETARGET_MODES:
        raise DmpError(f"unknown re-target mode {mode!r}; use one of {', '.join(RETARGET_MODES)}")
    demo_len = float(np.linalg.norm(demo_delta))
    target_len = float(np.linalg.norm(delta))
    if mode == "translate" or demo_len < ZERO_LENGTH_M:
        return np.eye(3)
    demo_dir = demo_delta / demo_len
    if target_len < ZERO_LENGTH_M:
        if mode == "axial":
            return np.eye(3) - np.outer(demo_dir, demo_dir)
        return np.eye(3)
    rotation = heading_rotation(demo_dir, delta / target_len, heading)
    ratio = target_len / demo_len
    if mode == "similarity":
        return ratio * rotation
    stretch = np.eye(3) + (ratio - 1.0) * np.outer(demo_dir, demo_dir)
    return rotation @ stretch


# --------------------------------------------------------------------------- exact discretization


@dataclass(frozen=True)
class _Filters:
    """IIR coefficients of the transformation system for one normalized step, zero initial state."""

    a: np.ndarray
    b_pos: np.ndarray
    b_vel: np.ndarray
    first_pos: np.ndarray
    """Impulse correction: output response to u[0] that the zero-history filter adds."""
    first_vel: np.ndarray


@functools.lru_cache(maxsize=64)
def _filters(step: float, stiffness: float, damping: float) -> _Filters:
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
    return _Filters(a, b_pos, b_vel, first_pos, first_vel)


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


def _workspace(name: str, shape: tuple[int, ...]) -> np.ndarray:
    """A per-thread scratch array (contents undefined), reused across fits: large temporaries
    would otherwise be fresh memory mappings, and page faults, on every call."""
    pool: dict[str, np.ndarray] = _WORKSPACE.__dict__.setdefault("pool", {})
    array = pool.get(name)
    if array is None or array.shape != shape:
        array = pool[name] = np.empty(shape)
    return array


def _respond(filters: _Filters, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


# --------------------------------------------------------------------------- the DMP


def basis_centers_widths(n_basis: int, alpha_s: float = ALPHA_S) -> tuple[np.ndarray, np.ndarray]:
    """Phase centres of Gaussians spread evenly in time, with widths equal in time."""
    times = np.linspace(0.0, 1.0, n_basis)
    centers = np.exp(-alpha_s * times)
    spacing = 1.0 / max(n_basis - 1, 1)
    widths = 1.0 / (2.0 * (spacing * alpha_s * centers) ** 2)
    return centers, widths


def _validate_demo(t: np.ndarray, y: np.ndarray, where: str) -> None:
    if t.ndim != 1 or y.ndim != 2 or y.shape[1] != 3 or y.shape[0] != t.shape[0]:
        raise DmpError(
            f"{where}: expected t of shape (T,) and y of shape (T, 3), got {t.shape} and {y.shape}"
        )
    if t.shape[0] < 10:
        raise DmpError(f"{where}: needs at least 10 samples, got {t.shape[0]}")
    if not (np.isfinite(t).all() and np.isfinite(y).all()):
        raise DmpError(f"{where}: contains NaN or infinite values")
    steps = np.diff(t)
    if (steps <= 0).any():
        index = int(np.argmax(steps <= 0)) + 1
        raise DmpError(f"{where}: time must increase strictly (sample {index}: t = {t[index]})")


@dataclass(frozen=True, eq=False)
class DMP:
    """A 3D discrete DMP fitted to one demonstration (its start, goal and duration kept)."""

    weights: np.ndarray
    """(n_basis, 3) forcing-term weights, metres."""
    demo_start: np.ndarray
    demo_goal: np.ndarray
    demo_duration: float
    """Seconds; the default tau."""
    alpha_z: float = ALPHA_Z
    beta_z: float = BETA_Z
    alpha_s: float = ALPHA_S
    _cache: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(
        default_factory=dict, repr=False, compare=False
    )

    @property
    def n_basis(self) -> int:
        return int(self.weights.shape[0])

    @property
    def demo_delta(self) -> np.ndarray:
        return self.demo_goal - self.demo_start

    # ---------------------------------------------------------------- fitting

    @classmethod
    def fit(
        cls,
        t: Sequence[float] | np.ndarray,
        y: Sequence[Sequence[float]] | np.ndarray,
        n_basis: int = 50,
        *,
        regularization: float = 1e-9,
    ) -> DMP:
        """Fit by one regularized least-squares solve on positions (time stamps need not be
        uniform): the rollout is linear in the weights, so each basis function's response is a
        column and the demo's own start, goal and duration fix the rest. The end is pinned to
        the demonstrated goal at rest."""
        t_arr = np.asarray(t, dtype=float)
        y_arr = np.asarray(y, dtype=float)
        _validate_demo(t_arr, y_arr, "demonstration")
        if not 2 <= int(n_basis) <= 1000:
            raise DmpError(f"n_basis must be between 2 and 1000, got {n_basis}")
        n_basis = int(n_basis)
        duration = float(t_arr[-1] - t_arr[0])
        phase_time = (t_arr - t_arr[0]) / duration
        start, goal = y_arr[0].copy(), y_arr[-1].copy()
        basis = _fit_basis(phase_time, n_basis, regularization)
        delta = goal - start
        target = (y_arr - start) - np.outer(basis.goal_position, delta)
        weights = np.ascontiguousarray(basis.solve(target, -basis.goal_end_velocity * delta))
        return cls(weights=weights, demo_start=start, demo_goal=goal, demo_duration=duration)

    # ---------------------------------------------------------------- rollout

    def forcing(self, s: np.ndarray) -> np.ndarray:
        """f(s) for phases s: (N,) -> (N, 3), before the re-targeting map."""
        s = np.asarray(s, dtype=float)
        scratch = _workspace("features", (self.n_basis, len(s)))
        return _phase_features(s, self.n_basis, self.alpha_s, out=scratch).T @ self.weights

    def _canonical(self, num: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Normalized-time rollout for the demo's start and goal, relative to the start: (p, dp,
        ddp) with derivatives per unit of normalized time. Cached per number of samples."""
        cached = self._cache.get(num)
        if cached is not None:
            return cached
        stiffness, damping = self.alpha_z * self.beta_z, self.alpha_z
        grid = np.linspace(0.0, 1.0, num)
        s = np.exp(-self.alpha_s * grid)
        u = stiffness * (np.outer(1.0 - s, self.demo_delta) + self.forcing(s))
        pos, vel = _respond(_filters(float(grid[1]), stiffness, damping), u)
        acc = u - stiffness * pos - damping * vel
        for array in (pos, vel, acc):
            array.flags.writeable = False
        if len(self._cache) >= _MAX_CACHED_GRIDS:
            self._cache.pop(next(iter(self._cache)))
        self._cache[num] = (pos, vel, acc)
        return pos, vel, acc

    def rollout(
        self,
        start: Sequence[float] | np.ndarray,
        goal: Sequence[float] | np.ndarray,
        tau: float | None = None,
        num: int = 1000,
        mode: str = "similarity",
        heading: float | None = None,
    ) -> Rollout:
        """Positions, velocities and accelerations from start towards goal over tau seconds
        (default: the demonstration's duration), num samples including both ends. `heading`
        (radians about z) orients the demo when the segment is vertical."""
        start_arr = _point(start, "start")
        goal_arr = _point(goal, "goal")
        tau = self.demo_duration if tau is None else float(tau)
        if not (math.isfinite(tau) and tau > 0):
            raise DmpError(f"tau must be a positive number of seconds, got {tau}")
        if int(num) < 2:
            raise DmpError(f"num must be at least 2, got {num}")
        transform = retarget_map(self.demo_delta, goal_arr - start_arr, mode, heading)
        pos, vel, acc = self._canonical(int(num))
        return Rollout(
            t=np.linspace(0.0, tau, int(num)),
            y=start_arr + pos @ transform.T,
            yd=vel @ (transform.T / tau),
            ydd=acc @ (transform.T / tau**2),
            transform=transform,
        )

    def integrate(
        self,
        start: Sequence[float] | np.ndarray,
        goal: Sequence[float] | np.ndarray,
        transform: np.ndarray,
        tau: float | None = None,
        num: int = 1000,
    ) -> Rollout:
        """Integrate the transformation system itself for this start, goal and map S (no
        re-use of the canonical rollout): the reference that `rollout` must agree with."""
        start_arr = _point(start, "start")
        goal_arr = _point(goal, "goal")
        tau = self.demo_duration if tau is None else float(tau)
        stiffness, damping = self.alpha_z * self.beta_z, self.alpha_z
        grid = np.linspace(0.0, 1.0, int(num))
        s = np.exp(-self.alpha_s * grid)
        delta = goal_arr - start_arr
        u = stiffness * (np.outer(1.0 - s, delta) + self.forcing(s) @ np.asarray(transform).T)
        pos, vel = _respond(_filters(float(grid[1]), stiffness, damping), u)
        acc = u - stiffness * pos - damping * vel
        return Rollout(
            t=grid * tau,
            y=start_arr + pos,
            yd=vel / tau,
            ydd=acc / tau**2,
            transform=np.asarray(transform, dtype=float),
        )

    def path_length(self, start: np.ndarray, goal: np.ndarray, mode: str = "similarity") -> float:
        """Length in metres of the re-targeted path (from the cached canonical rollout)."""
        transform = retarget_map(self.demo_delta, np.asarray(goal) - np.asarray(start), mode)
        pos = self._canonical(1000)[0] @ transform.T
        return float(np.linalg.norm(np.diff(pos, axis=0), axis=1).sum())

    def tau_for_speed(
        self, start: np.ndarray, goal: np.ndarray, speed: float, mode: str = "similarity"
    ) -> float:
        """Duration that makes the re-targeted path run at `speed` m/s on average (temporal
        scaling); paths shorter than 0.1 mm keep the demonstration's duration."""
        if not (math.isfinite(speed) and speed > 0):
            raise DmpError(f"speed must be a positive number of m/s, got {speed}")
        length = self.path_length(start, goal, mode)
        return self.demo_duration if length < 1e-4 else length / speed

    # ---------------------------------------------------------------- (de)serialization

    def to_dict(self) -> dict[str, Any]:
        """Plain Python values (floats as written by repr round-trip exactly)."""
        return {
            "n_basis": self.n_basis,
            "alpha_z": self.alpha_z,
            "beta_z": self.beta_z,
            "alpha_s": self.alpha_s,
            "demo_duration": self.demo_duration,
            "demo_start": [float(v) for v in self.demo_start],
            "demo_goal": [float(v) for v in self.demo_goal],
            "weights": [[float(v) for v in row] for row in self.weights],
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any], where: str = "DMP") -> DMP:
        """Inverse of to_dict; every problem raises DmpError naming `where` and the field."""
        if not isinstance(data, dict):
            raise DmpError(f"{where}: dmp must be a mapping")
        for key in ("n_basis", "demo_duration", "demo_start", "demo_goal", "weights"):
            if key not in data:
                raise DmpError(f"{where}: dmp.{key} is missing")
        try:
            weights = np.asarray(data["weights"], dtype=float)
            start = np.asarray(data["demo_start"], dtype=float)
            goal = np.asarray(data["demo_goal"], dtype=float)
            n_basis = int(data["n_basis"])
            duration = float(data["demo_duration"])
            gains = {k: float(data.get(k, d)) for k, d in _GAIN_DEFAULTS.items()}
        except (TypeError, ValueError) as error:
            raise DmpError(f"{where}: dmp has a non-numeric value ({error})") from None
        if weights.ndim != 2 or weights.shape[1] != 3:
            raise DmpError(f"{where}: dmp.weights must be a list of [wx, wy, wz] rows")
        if weights.shape[0] != n_basis:
            raise DmpError(
                f"{where}: dmp.weights has {weights.shape[0]} rows but dmp.n_basis is {n_basis}"
            )
        if start.shape != (3,) or goal.shape != (3,):
            raise DmpError(f"{where}: dmp.demo_start and dmp.demo_goal must be [x, y, z]")
        values = np.concatenate([weights.ravel(), start, goal, [duration, *gains.values()]])
        if not np.isfinite(values).all():
            raise DmpError(f"{where}: dmp contains NaN or infinite values")
        if duration <= 0:
            raise DmpError(f"{where}: dmp.demo_duration must be positive, got {duration}")
        return cls(
            weights=weights,
            demo_start=start,
            demo_goal=goal,
            demo_duration=duration,
            alpha_z=gains["alpha_z"],
            beta_z=gains["beta_z"],
            alpha_s=gains["alpha_s"],
        )


_GAIN_DEFAULTS = {"alpha_z": ALPHA_Z, "beta_z": BETA_Z, "alpha_s": ALPHA_S}


def _phase_features(
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
class _FitBasis:
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


_FIT_BASES: dict[tuple[int, int, float], _FitBasis] = {}


def _fit_basis(phase_time: np.ndarray, n_basis: int, regularization: float) -> _FitBasis:
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
    inputs = _workspace("inputs", (n_basis + 1, num))
    _phase_features(s, n_basis, ALPHA_S, out=inputs[:n_basis])
    inputs[:n_basis] *= stiffness
    np.multiply(stiffness, 1.0 - s, out=inputs[n_basis])
    filters = _filters(float(grid[1]), stiffness, damping)
    pos = _fir(filters.b_pos, inputs, np.empty_like(inputs), _workspace("fir", inputs.shape))
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
    basis = _FitBasis(
        weighted_design=weighted,
        end_position=design[:, -1].copy(),
        end_velocity=vel_end[:n_basis].copy(),
        goal_position=pos[n_basis],
        goal_end_velocity=float(vel_end[n_basis]),
        factor=cho_factor(gram, lower=False, check_finite=False),
    )
    if uniform:
        if len(_FIT_BASES) >= _MAX_CACHED_GRIDS:
            _FIT_BASES.pop(next(iter(_FIT_BASES)))
        _FIT_BASES[key] = basis
    return basis


def clear_caches() -> None:
    """Forget cached fit bases and discretizations (for cold-start timing)."""
    _FIT_BASES.clear()
    _filters.cache_clear()


def _interp_rows(grid: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Linear interpolation of every column of values (sampled on grid) at the times `at`."""
    index = np.clip(np.searchsorted(grid, at, side="right") - 1, 0, len(grid) - 2)
    frac = ((at - grid[index]) / (grid[index + 1] - grid[index]))[:, None]
    return values[index] * (1.0 - frac) + values[index + 1] * frac


def _point(value: Sequence[float] | np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise DmpError(f"{name} must be a finite [x, y, z] point, got {value!r}")
    return arr
