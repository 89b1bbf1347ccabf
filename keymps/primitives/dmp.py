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

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from keymps.primitives.filters import workspace
from keymps.primitives.retarget import RETARGET_MODES, ZERO_LENGTH_M, heading_rotation, retarget_map
from keymps.primitives.system import (
    ALPHA_S,
    ALPHA_Z,
    BETA_Z,
    MAX_CACHED_GRIDS,
    DmpError,
    basis_centers_widths,
    clear_caches,
    discretize,
    fit_basis,
    phase_features,
    respond,
)

__all__ = [
    "ALPHA_S",
    "ALPHA_Z",
    "BETA_Z",
    "DMP",
    "RETARGET_MODES",
    "ZERO_LENGTH_M",
    "DmpError",
    "RetargetMode",
    "Rollout",
    "basis_centers_widths",
    "clear_caches",
    "heading_rotation",
    "retarget_map",
]

RetargetMode = Literal["similarity", "axial", "blade", "translate"]


@dataclass(frozen=True)
class Rollout:
    """A sampled DMP trajectory: positions, velocities and accelerations in metres and seconds."""

    t: np.ndarray
    """(num,) seconds from the start of the primitive."""
    y: np.ndarray
    """(num, 3) positions, metres."""
    yd: np.ndarray
    """(num, 3) velocities, m/s."""
    ydd: np.ndarray
    """(num, 3) accelerations, m/s^2."""
    transform: np.ndarray = field(default_factory=lambda: np.eye(3))
    """The 3x3 map S applied to the demonstration (S (g_d - y0_d) = reached goal - start)."""

    @property
    def length_m(self) -> float:
        """Length of the sampled path, metres."""
        return float(np.linalg.norm(np.diff(self.y, axis=0), axis=1).sum())


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
    """A 3D discrete DMP fitted to one demonstration (its start, goal and duration kept).

    ```python
    dmp = DMP.fit(t, y)                       # t (T,) seconds, y (T, 3) metres
    cut = dmp.rollout(start=[0.1, 0.0, 0.05], goal=[0.1, 0.1, 0.0], tau=2.0)
    cut.y                                     # (1000, 3): the demo carried onto the segment
    ```
    """

    weights: np.ndarray
    """(n_basis, 3) forcing-term weights, metres."""
    demo_start: np.ndarray
    """(3,) the demonstration's first position, metres."""
    demo_goal: np.ndarray
    """(3,) the demonstration's last position, metres."""
    demo_duration: float
    """Seconds; the default tau."""
    alpha_z: float = ALPHA_Z
    """Damping gain (D = alpha_z), 1/s in normalized time; the same on every axis."""
    beta_z: float = BETA_Z
    """Stiffness ratio (K = alpha_z beta_z); alpha_z / 4 makes the system critically damped."""
    alpha_s: float = ALPHA_S
    """Decay rate of the phase s (tau s' = -alpha_s s)."""
    _cache: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(
        default_factory=dict, repr=False, compare=False
    )

    @property
    def n_basis(self) -> int:
        """Number of Gaussian basis functions per axis."""
        return int(self.weights.shape[0])

    @property
    def demo_delta(self) -> np.ndarray:
        """(3,) goal minus start of the demonstration, metres."""
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
        """Fit by one regularized least-squares solve on positions.

        The rollout is linear in the weights, so each basis function's response is a column and
        the demo's own start, goal and duration fix the rest. The end is pinned to the
        demonstrated goal at rest. Time stamps need not be uniform.

        Args:
            t: (T,) strictly increasing time stamps, seconds, T >= 10.
            y: (T, 3) positions, metres.
            n_basis: Gaussian basis functions per axis, 2 to 1000.
            regularization: Ridge term, a fraction of the normal equations' mean diagonal.

        Returns:
            The fitted DMP.

        Raises:
            DmpError: For shapes that do not match, too few samples, NaN or infinite values,
                time that does not increase, or n_basis out of range.
        """
        t_arr = np.asarray(t, dtype=float)
        y_arr = np.asarray(y, dtype=float)
        _validate_demo(t_arr, y_arr, "demonstration")
        if not 2 <= int(n_basis) <= 1000:
            raise DmpError(f"n_basis must be between 2 and 1000, got {n_basis}")
        n_basis = int(n_basis)
        duration = float(t_arr[-1] - t_arr[0])
        phase_time = (t_arr - t_arr[0]) / duration
        start, goal = y_arr[0].copy(), y_arr[-1].copy()
        basis = fit_basis(phase_time, n_basis, regularization)
        delta = goal - start
        target = (y_arr - start) - np.outer(basis.goal_position, delta)
        weights = np.ascontiguousarray(basis.solve(target, -basis.goal_end_velocity * delta))
        return cls(weights=weights, demo_start=start, demo_goal=goal, demo_duration=duration)

    # ---------------------------------------------------------------- rollout

    def forcing(self, s: np.ndarray) -> np.ndarray:
        """The forcing term before the re-targeting map.

        Args:
            s: (N,) phases, in (0, 1].

        Returns:
            (N, 3) f(s), metres.
        """
        s = np.asarray(s, dtype=float)
        scratch = workspace("features", (self.n_basis, len(s)))
        return phase_features(s, self.n_basis, self.alpha_s, out=scratch).T @ self.weights

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
        pos, vel = respond(discretize(float(grid[1]), stiffness, damping), u)
        acc = u - stiffness * pos - damping * vel
        for array in (pos, vel, acc):
            array.flags.writeable = False
        if len(self._cache) >= MAX_CACHED_GRIDS:
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
        """The demonstration re-targeted to a start and goal, sampled uniformly in time.

        Exact: y(t) = start + S (y_fit(t) - demo_start), with S = retarget_map(demo_delta,
        goal - start, mode, heading) and y_fit the fit's own rollout, cached per `num`.

        Args:
            start: (3,) where the motion starts, metres.
            goal: (3,) where it ends at rest, metres.
            tau: Duration, seconds; None takes the demonstration's.
            num: Samples, both ends included, at least 2.
            mode: One of RETARGET_MODES.
            heading: Radians about z: orients the demo when the segment is vertical.

        Returns:
            Times (num,), positions, velocities, accelerations (num, 3) and the map S.

        Raises:
            DmpError: For a start or goal that is not a finite [x, y, z], tau <= 0, num < 2 or
                an unknown mode.
        """
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
        """Integrate the transformation system itself for this start, goal and map S.

        No re-use of the canonical rollout: the reference that `rollout` must agree with.

        Args:
            start: (3,) where the motion starts, metres.
            goal: (3,) where it ends at rest, metres.
            transform: (3, 3) the map S applied to the forcing term.
            tau: Duration, seconds; None takes the demonstration's.
            num: Samples, both ends included.

        Returns:
            Times (num,), positions, velocities and accelerations (num, 3), and `transform`.

        Raises:
            DmpError: For a start or goal that is not a finite [x, y, z].
        """
        start_arr = _point(start, "start")
        goal_arr = _point(goal, "goal")
        tau = self.demo_duration if tau is None else float(tau)
        stiffness, damping = self.alpha_z * self.beta_z, self.alpha_z
        grid = np.linspace(0.0, 1.0, int(num))
        s = np.exp(-self.alpha_s * grid)
        delta = goal_arr - start_arr
        u = stiffness * (np.outer(1.0 - s, delta) + self.forcing(s) @ np.asarray(transform).T)
        pos, vel = respond(discretize(float(grid[1]), stiffness, damping), u)
        acc = u - stiffness * pos - damping * vel
        return Rollout(
            t=grid * tau,
            y=start_arr + pos,
            yd=vel / tau,
            ydd=acc / tau**2,
            transform=np.asarray(transform, dtype=float),
        )

    def path_length(self, start: np.ndarray, goal: np.ndarray, mode: str = "similarity") -> float:
        """Length of the re-targeted path (from the cached canonical rollout).

        Args:
            start: (3,) where the motion starts, metres.
            goal: (3,) where it ends, metres.
            mode: One of RETARGET_MODES.

        Returns:
            The path's length, metres.
        """
        delta = _point(goal, "goal") - _point(start, "start")
        transform = retarget_map(self.demo_delta, delta, mode)
        pos = self._canonical(1000)[0] @ transform.T
        return float(np.linalg.norm(np.diff(pos, axis=0), axis=1).sum())

    def tau_for_speed(
        self, start: np.ndarray, goal: np.ndarray, speed: float, mode: str = "similarity"
    ) -> float:
        """The duration that runs the re-targeted path at a given average speed.

        Args:
            start: (3,) where the motion starts, metres.
            goal: (3,) where it ends, metres.
            speed: Average tool speed along the path, m/s.
            mode: One of RETARGET_MODES.

        Returns:
            tau, seconds; paths shorter than 0.1 mm keep the demonstration's duration.

        Raises:
            DmpError: For a speed that is not a positive number.
        """
        if not (math.isfinite(speed) and speed > 0):
            raise DmpError(f"speed must be a positive number of m/s, got {speed}")
        length = self.path_length(start, goal, mode)
        return self.demo_duration if length < 1e-4 else length / speed

    # ---------------------------------------------------------------- (de)serialization

    def to_dict(self) -> dict[str, Any]:
        """The DMP as plain Python values (a primitive file's `dmp` block).

        Returns:
            n_basis, the gains, demo_duration, demo_start, demo_goal and weights as lists of
            floats (repr round-trips them exactly).
        """
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
        """The inverse of `to_dict`.

        Args:
            data: A mapping as `to_dict` writes it (gains may be left out: the defaults).
            where: Names the source in messages (a primitive file's path).

        Returns:
            The DMP.

        Raises:
            DmpError: For a missing field, a value that is no number, NaN or infinite values,
                wrong shapes, or a duration that is not positive, naming `where` and the field.
        """
        if not isinstance(data, dict):
            raise DmpError(f"{where}: dmp must be a mapping")
        for key in ("n_basis", "demo_duration", "demo_start", "demo_goal", "weights"):
            if key not in data:
                raise DmpError(f"{where}: dmp.{key} is missing")
        _check_weight_rows(data["weights"], where)
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


def _check_weight_rows(rows: Any, where: str) -> None:
    """Weights that are not a list of rows of three, with the bad row named by its index
    (numpy's own message would not say which)."""
    if not isinstance(rows, (list, tuple)):
        raise DmpError(f"{where}: dmp.weights must be a list of [wx, wy, wz] rows")
    for index, row in enumerate(rows):
        if not isinstance(row, (list, tuple)) or len(row) != 3:
            size = f"{len(row)} values" if isinstance(row, (list, tuple)) else repr(row)
            raise DmpError(
                f"{where}: dmp.weights row {index + 1} is {size}; each row is [wx, wy, wz]"
            )


def _point(value: Sequence[float] | np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise DmpError(f"{name} must be a finite [x, y, z] point, got {value!r}")
    return arr
