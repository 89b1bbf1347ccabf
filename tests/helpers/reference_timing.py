"""The timing one stroke and one profile at a time: what keymps.motion.timing's batched paths
replaced, kept as the reference they are held against (tests/motion/test_timing_fast_paths.py)
and measured against (benchmarks/perf/pipeline.py).

`time_stroke` is `time_strokes_at_once` for one stroke: the same profiles, limits, slowdowns and
places to stop at, checked on its own 1 kHz sampling.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from keymps.motion.strokes import Stroke
from keymps.motion.timing import (
    CHECK_RATE_HZ,
    LIMIT_MARGIN,
    MAX_RETIMES,
    STOP_SLOWDOWN,
    Limits,
    TimedStroke,
    _profile,
    _sample_profile_by_calls,
    _tail,
    _untimeable,
    _worst_place,
)
from keymps.robot.model import RobotModel


def sample_profile(profile: Any, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration of a 1-DOF Ruckig profile at `times` (each (m,)).

    A Ruckig profile is seven constant-jerk phases: inside a phase the state is the cubic
    Ruckig's own `at_time` integrates (same formula, same order of operations), evaluated here
    for all times at once; past the end the final state continues at zero jerk, as in Ruckig.
    """
    phases = profile.profiles[0][0]
    if len(profile.profiles) != 1 or phases.brake.duration > 0:
        return _sample_profile_by_calls(profile, times)  # never for rest-to-rest strokes
    t_sum = np.cumsum(phases.t)
    jerk = np.append(np.asarray(phases.j, dtype=float), 0.0)
    p0, v0, a0 = (np.asarray(values, dtype=float) for values in (phases.p, phases.v, phases.a))
    times = np.asarray(times, dtype=float)
    index = np.searchsorted(t_sum, times, side="right")  # Ruckig's upper_bound
    start = np.concatenate([[0.0], t_sum])[index]
    t = times - start
    j, a, v, p = jerk[index], a0[index], v0[index], p0[index]
    position = p + t * (v + t * (a / 2 + t * j / 6))
    velocity = v + t * (a + t * j / 2)
    acceleration = a + t * j
    return position, velocity, acceleration


def joint_motion(
    stroke: Stroke, s: np.ndarray, sd: np.ndarray, sdd: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, q dot, q double dot (each (m, 6)) from q(s) and the timing of s (chain rule)."""
    s = np.clip(s, 0.0, stroke.length)
    q, dq, ddq = stroke.q_of_s.with_derivatives(s)
    return q, dq * sd[:, None], ddq * (sd**2)[:, None] + dq * sdd[:, None]


def joint_rates(
    stroke: Stroke, s: np.ndarray, sd: np.ndarray, sdd: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """q dot and q double dot of `joint_motion`, without q (the limit check needs no more)."""
    dq, ddq = stroke.q_of_s.derivatives(np.clip(s, 0.0, stroke.length))
    return dq * sd[:, None], ddq * (sd**2)[:, None] + dq * sdd[:, None]


def limit_ratios(
    model: RobotModel, qd: np.ndarray, qdd: np.ndarray, period: float
) -> tuple[float, float, float]:
    """The largest |qd|/limit, |qdd|/limit, |jerk|/limit (jerk by differences of qdd)."""
    velocity = float((np.abs(qd) / model.velocity_limits).max())
    acceleration = float((np.abs(qdd) / model.acceleration_limits).max())
    jerk = np.diff(qdd, axis=0) / period if len(qdd) > 1 else np.zeros((1, 6))
    return velocity, acceleration, float((np.abs(jerk) / model.jerk_limits).max())


def time_stroke(
    model: RobotModel, stroke: Stroke, tool_limits: Limits, period: float
) -> TimedStroke:
    """The fastest profile (tool limits first) whose joints stay inside every joint limit."""
    limits = Limits(min(stroke.speed, tool_limits.velocity), *_tail(tool_limits))
    check_period = min(period, 1.0 / CHECK_RATE_HZ)
    first_duration, first_place = None, 0.0
    for attempt in range(MAX_RETIMES):
        profile, duration = _profile(stroke.length, limits, period)
        times = np.arange(0.0, duration + 0.5 * check_period, check_period)
        times[-1] = min(times[-1], duration)
        s, sd, sdd = sample_profile(profile, times)
        qd, qdd = joint_rates(stroke, s, sd, sdd)
        if first_duration is None:
            first_duration = duration
            first_place = _worst_place(model, s, qd, qdd, check_period)
        rv, ra, rj = limit_ratios(model, qd, qdd, check_period)
        if max(rv, ra, rj) <= 1.0:
            slowdown = duration / first_duration
            worst_s = first_place if slowdown >= STOP_SLOWDOWN else 0.0
            return TimedStroke(stroke, profile, duration, limits, slowdown, worst_s)
        if attempt < MAX_RETIMES // 2:
            # lower only what is violated: keeps the profile fast where it can be
            limits = Limits(
                limits.velocity / max(rv / LIMIT_MARGIN, 1.0),
                limits.acceleration / max(ra / LIMIT_MARGIN, 1.0),
                limits.jerk / max(rj / LIMIT_MARGIN, 1.0),
            )
        else:
            limits = limits.scaled(max(rv, math.sqrt(ra), rj ** (1 / 3)) / LIMIT_MARGIN)
    raise _untimeable(stroke)


def planned_points(stroke: Stroke, s: np.ndarray) -> np.ndarray:
    """(m, 3) the tool path's polyline at arc parameter s (what the tool should be doing)."""
    s = np.clip(s, 0.0, stroke.length)
    return np.column_stack([np.interp(s, stroke.s, stroke.points[:, k]) for k in range(3)])
