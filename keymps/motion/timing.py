"""Time a tool path: jerk-limited Ruckig profiles on the arc length of each stroke.

Community Ruckig has no offline intermediate waypoints, so every stroke (a part of a piece
between sharp corners, starting and ending at rest) gets a 1-DOF state-to-state profile of its
path parameter s. The tool path is mapped to joints through the IK solution (a cubic spline
q(s) through IK points at most 2 mm apart), then joint velocity, acceleration and jerk are
checked on a 1 kHz sampling and a stroke that breaks a limit is slowed down and re-timed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.errors import KeympsError
from keymps.motion.spline import CubicSpline, SplineTable
from keymps.motion.strokes import ShiftedPath, Stroke, split_stroke, split_strokes
from keymps.types import JointPath, ToolPath, Trajectory

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.robot.model import RobotModel

CHECK_RATE_HZ = 1000.0
LIMIT_MARGIN = 0.98
"""Slowed-down strokes aim this far inside the violated limit."""
MAX_RETIMES = 12
STOP_SLOWDOWN = 1.5
"""A stroke the joint limits slow down this much is tried with a stop where it breaks them."""
MAX_STOP_DEPTH = 4
"""At most this many nested stops per stroke (up to 2**4 parts)."""
SLOW_PIECE_FACTOR = 2.0
"""A work piece the joint limits make this many times slower than the tool limits alone
(motion.work_speed, the tool's acceleration and jerk) gets a run warning."""


@dataclass(frozen=True)
class Limits:
    """Limits of the path parameter s for one stroke."""

    velocity: float
    acceleration: float
    jerk: float

    def scaled(self, factor: float) -> Limits:
        """The same profile shape, `factor` times slower."""
        return Limits(self.velocity / factor, self.acceleration / factor**2, self.jerk / factor**3)


@dataclass
class TimedStroke:
    """A stroke with its Ruckig profile of s, duration and the limits it was timed at."""

    stroke: Stroke
    profile: Any
    """ruckig.Trajectory of s."""
    duration: float
    limits: Limits
    slowdown: float
    """Duration relative to the profile with the tool limits alone (1.0: no joint limit hit)."""
    worst_s: float = 0.0
    """Where (arc parameter) the profile at the tool limits broke the joint limits most; only
    for a stroke slowed down STOP_SLOWDOWN times or more (0.0 for the others)."""
    nominal: float = 0.0
    """This stroke's share of the time the stroke it was split from takes at the tool limits
    alone (set by time_strokes)."""


def _profile(
    length: float, limits: Limits, period: float, stroke: Stroke | None = None
) -> tuple[Any, float]:
    """Rest-to-rest Ruckig profile of s over `length`, its duration a multiple of `period`;
    when Ruckig refuses it, a KeympsError naming the stroke, its limits and Ruckig's reason."""
    from keymps.interrupts import import_whole

    ruckig = import_whole("ruckig")
    request = ruckig.InputParameter(1)
    request.current_position = [0.0]
    request.target_position = [length]
    request.max_velocity = [limits.velocity]
    request.max_acceleration = [limits.acceleration]
    request.max_jerk = [limits.jerk]
    generator = ruckig.Ruckig(1)
    profile = ruckig.Trajectory(1)
    refused = _calculate(ruckig, generator, request, profile)
    if refused is not None:
        raise _refusal(f"time {_named(stroke, length)}", limits, refused)
    rounded = math.ceil(profile.duration / period - 1e-9) * period
    if rounded - profile.duration > 1e-12:
        request.minimum_duration = rounded
        refused = _calculate(ruckig, generator, request, profile)
        if refused is not None:
            raise _refusal(f"stretch {_named(stroke, length)} to {rounded:.3f} s", limits, refused)
    return profile, rounded


def _calculate(ruckig: Any, generator: Any, request: Any, profile: Any) -> str | None:
    """Ruckig's calculation of `profile`: None, or Ruckig's reason for refusing it (its result,
    or its exception's)."""
    try:
        result = generator.calculate(request, profile)
    except (getattr(ruckig, "RuckigError", RuntimeError), RuntimeError) as error:
        return _ruckig_reason(error)  # (RuntimeError: a ruckig without RuckigError)
    return None if result in (ruckig.Result.Working, ruckig.Result.Finished) else str(result)


def _named(stroke: Stroke | None, length: float) -> str:
    """'a 0.1000 m stroke of piece 2 (work)', or without the piece when the stroke is unknown."""
    which = f" of piece {stroke.piece_index} ({stroke.kind})" if stroke is not None else ""
    return f"a {length:.4f} m stroke{which}"


def _refusal(doing: str, limits: Limits, reason: str) -> KeympsError:
    """One line: what Ruckig could not do, at which limits of s, and Ruckig's reason."""
    return KeympsError(
        f"timing: Ruckig could not {doing} at velocity {limits.velocity:.4g} m/s, acceleration "
        f"{limits.acceleration:.4g} m/s^2, jerk {limits.jerk:.4g} m/s^3: {reason}"
    )


def _ruckig_reason(error: Exception) -> str:
    """The first line of a RuckigError (the rest repeats the whole input), without its tag."""
    lines = str(error).strip().splitlines()
    first = lines[0].strip() if lines else ""
    first = first.removeprefix("[ruckig]").strip().removesuffix("input:").strip(" ,.")
    return first or type(error).__name__


def _sample_profile_by_calls(
    profile: Any, times: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration of a Ruckig profile at `times`, one Ruckig call per
    time: for a profile that is not one rest-to-rest phase list (never one of `_profile`'s)."""
    values = np.array([[v[0] for v in profile.at_time(float(t))] for t in times])
    return values[:, 0], values[:, 1], values[:, 2]


def _sample_profiles(
    profiles: list[Any], times: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration of 1-DOF Ruckig profiles, `times[k]` on
    `profiles[k]`, end to end.

    A Ruckig profile is seven constant-jerk phases: inside a phase the state is the cubic
    Ruckig's own `at_time` integrates (same formula, same order of operations), evaluated here
    for all samples in one pass after a phase search per profile; past the end the final state
    continues at zero jerk, as in Ruckig.
    """
    count = len(profiles)
    phase_lists: list[list[Any]] = [[], [], [], [], []]
    by_calls = []
    for k, profile in enumerate(profiles):
        every = profile.profiles  # (a copy of Ruckig's profiles: read once)
        phases = every[0][0]
        if len(every) != 1 or phases.brake.duration > 0:
            by_calls.append(k)  # never for rest-to-rest strokes
            for values, size in zip(phase_lists, (7, 7, 8, 8, 8), strict=True):
                values.append([0.0] * size)
            continue
        for values, name in zip(phase_lists, ("t", "j", "a", "v", "p"), strict=True):
            values.append(getattr(phases, name))
    durations, jerks, a0, v0, p0 = (np.array(values, dtype=float) for values in phase_lists)
    starts = np.zeros((count, 8))
    starts[:, 1:] = np.cumsum(durations, axis=1)  # row by row, as np.cumsum(phases.t)
    states = np.zeros((4, count, 8))  # jerk, acceleration, velocity, position per phase
    states[0, :, :7], states[1], states[2], states[3] = jerks, a0, v0, p0
    index = [
        np.searchsorted(starts[k, 1:], at, side="right") + 8 * k  # Ruckig's upper_bound
        for k, at in enumerate(times)
    ]
    flat = np.concatenate(index)
    all_times = np.concatenate(times)
    t = all_times - starts.ravel()[flat]
    j, a, v, p = (table.ravel()[flat] for table in states)
    position = p + t * (v + t * (a / 2 + t * j / 6))
    velocity = v + t * (a + t * j / 2)
    acceleration = a + t * j
    if by_calls:
        ends = np.cumsum([len(at) for at in times])
        for k in by_calls:
            part = slice(ends[k] - len(times[k]), ends[k])
            position[part], velocity[part], acceleration[part] = _sample_profile_by_calls(
                profiles[k], times[k]
            )
    return position, velocity, acceleration


class _StrokeRates:
    """q, q dot and q double dot of many strokes at once, from q(s) and the timing of s (chain
    rule): their splines in one SplineTable; a stroke whose q(s) is no CubicSpline (or a shift
    of one) is evaluated on its own."""

    def __init__(self, strokes: list[Stroke]):
        self.strokes = strokes
        self.offsets: list[list[float]] = []
        spline_of: list[CubicSpline | None] = []
        for stroke in strokes:
            q_of_s, offsets = stroke.q_of_s, []
            while isinstance(q_of_s, ShiftedPath):  # q(s + outer) = inner(s + outer + ...)
                offsets.append(q_of_s.offset)
                q_of_s = q_of_s.q_of_s
            self.offsets.append(offsets)
            spline_of.append(q_of_s if isinstance(q_of_s, CubicSpline) else None)
        self.table: SplineTable | None = None
        self.spline_index: list[int] = []
        if strokes and all(spline is not None for spline in spline_of):
            unique: dict[int, int] = {}
            splines: list[CubicSpline] = []
            for spline in spline_of:
                if id(spline) not in unique:
                    unique[id(spline)] = len(splines)
                    splines.append(spline)  # type: ignore[arg-type]
                self.spline_index.append(unique[id(spline)])
            shapes = {spline.c.shape[2] for spline in splines}
            if len(shapes) == 1:
                self.table = SplineTable(splines)

    def motion(
        self, k: int, s: np.ndarray, sd: np.ndarray, sdd: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, q dot and q double dot of stroke k, (m, 6) each, through the table."""
        chunks = list(self.chunks([k], s, [len(s)], sd, sdd))
        q, qd, qdd = (np.concatenate([c[i] for c in chunks], axis=1).T for i in (1, 2, 3))
        return q, qd, qdd

    def chunks(
        self,
        which: list[int],
        s: np.ndarray,
        counts: list[int],
        sd: np.ndarray,
        sdd: np.ndarray,
        values: bool = True,
    ) -> Iterator[tuple[slice, np.ndarray | None, np.ndarray, np.ndarray]]:
        """(samples, q or None, q dot, q double dot), each (6, m), chunk by chunk: `s` holds
        `counts[k]` samples on stroke `which[k]`, end to end with `sd` and `sdd`."""
        lengths = np.array([self.strokes[k].length for k in which])
        at = np.clip(s, 0.0, np.repeat(lengths, counts))
        starts = (np.cumsum(counts) - counts).tolist()
        if self.table is None:
            q_parts, dq_parts, ddq_parts = [], [], []
            for k, start, count in zip(which, starts, counts, strict=True):
                q_of_s, part = self.strokes[k].q_of_s, at[start : start + count]
                if values:
                    q_k, dq_k, ddq_k = q_of_s.with_derivatives(part)
                    q_parts.append(q_k)
                else:
                    dq_k, ddq_k = q_of_s.derivatives(part)
                dq_parts.append(dq_k)
                ddq_parts.append(ddq_k)
            q = np.concatenate(q_parts) if values else None
            dq, ddq = np.concatenate(dq_parts), np.concatenate(ddq_parts)
            qd, qdd = dq * sd[:, None], ddq * (sd**2)[:, None] + dq * sdd[:, None]
            yield slice(0, len(sd)), None if q is None else q.T, qd.T, qdd.T
            return
        for k, start, count in zip(which, starts, counts, strict=True):
            for offset in self.offsets[k]:  # as ShiftedPath adds them, outermost first
                at[start : start + count] = at[start : start + count] + offset
        rows = self.table.intervals([self.spline_index[k] for k in which], at, counts)
        for part, q, dq, ddq in self.table.chunks(at, rows, values):
            rate = sd[part]
            ddq *= rate**2  # q double dot: ddq * sd**2 + dq * sdd, in place
            ddq += dq * sdd[part]
            dq *= rate  # q dot
            yield part, q, dq, ddq


def _worst_place(
    model: RobotModel, s: np.ndarray, qd: np.ndarray, qdd: np.ndarray, period: float
) -> float:
    """The arc parameter where a profile breaks a joint limit by the largest factor."""
    velocity = (np.abs(qd) / model.velocity_limits).max(axis=1)
    acceleration = np.sqrt((np.abs(qdd) / model.acceleration_limits).max(axis=1))
    jerk = np.zeros(len(s))
    if len(s) > 1:
        jerk[1:] = np.cbrt((np.abs(np.diff(qdd, axis=0)) / period / model.jerk_limits).max(axis=1))
    return float(s[int(np.argmax(np.maximum(np.maximum(velocity, acceleration), jerk)))])


def _check_profiles(
    model: RobotModel,
    rates: _StrokeRates,
    which: list[int],
    profiles: list[Any],
    durations: list[float],
    check_period: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The largest |q dot|, |q double dot| and |jerk| (by differences of q double dot) over
    their joint limits, of every profile (on stroke `which[k]`) in one pass: (count,) each.

    Dividing by a limit is monotone, so the largest ratio is the largest magnitude per joint
    divided by its limit: the same number as dividing every sample first.
    """
    times = _check_times(durations, check_period)
    counts = np.array([len(at) for at in times])
    starts = np.cumsum(counts) - counts
    s, sd, sdd = _sample_profiles(profiles, times)
    joints = len(model.velocity_limits)
    largest = np.zeros((3, joints, len(counts)))  # |q dot|, |q double dot|, |change of it|
    before = None  # the last q double dot of the chunk before
    for part, _, qd, qdd in rates.chunks(which, s, counts.tolist(), sd, sdd, values=False):
        first = int(np.searchsorted(starts, part.start, side="right")) - 1
        last = int(np.searchsorted(starts, part.start + qd.shape[1], side="left"))
        owners = np.arange(first, last)  # the profiles with samples in this chunk
        cuts = np.maximum(starts[first:last] - part.start, 0)
        change = np.diff(qdd, axis=1)
        np.abs(change, out=change)
        change[:, cuts[1:] - 1] = 0.0  # from one profile's last sample to the next one's first
        inside = cuts < change.shape[1]
        if inside.any():
            found = np.maximum.reduceat(change, cuts[inside], axis=1)
            largest[2][:, owners[inside]] = np.maximum(largest[2][:, owners[inside]], found)
        if before is not None and starts[first] < part.start:
            # the change from the chunk before, inside one profile
            largest[2][:, first] = np.maximum(largest[2][:, first], np.abs(qdd[:, 0] - before))
        before = qdd[:, -1].copy()
        for slot, values in ((0, qd), (1, qdd)):
            np.abs(values, out=values)
            found = np.maximum.reduceat(values, cuts, axis=1)
            largest[slot][:, owners] = np.maximum(largest[slot][:, owners], found)
    velocity = (largest[0] / model.velocity_limits[:, None]).max(axis=0)
    acceleration = (largest[1] / model.acceleration_limits[:, None]).max(axis=0)
    jerk = (largest[2] / check_period / model.jerk_limits[:, None]).max(axis=0)
    return velocity, acceleration, jerk


def _check_times(durations: list[float], check_period: float) -> list[np.ndarray]:
    """The limit check's sampling of profiles of these durations (the end included)."""
    times = []
    for duration in durations:
        at = np.arange(0.0, duration + 0.5 * check_period, check_period)
        at[-1] = min(at[-1], duration)
        times.append(at)
    return times


def _worst_places(
    model: RobotModel,
    rates: _StrokeRates,
    which: list[int],
    profiles: list[Any],
    durations: list[float],
    check_period: float,
) -> list[float]:
    """`_worst_place` of each profile (on stroke `which[k]`)."""
    places = []
    for k, profile, at in zip(which, profiles, _check_times(durations, check_period), strict=True):
        s, sd, sdd = _sample_profiles([profile], [at])
        _, qd, qdd = rates.motion(k, s, sd, sdd)
        places.append(_worst_place(model, s, qd, qdd, check_period))
    return places


def time_strokes_at_once(
    model: RobotModel, strokes: list[Stroke], tool_limits: Limits, period: float
) -> list[TimedStroke | KeympsError]:
    """Each stroke's fastest profile (tool limits first) whose joints keep every joint limit at
    CHECK_RATE_HZ (or 1 / period if faster), each round's checks of all strokes still too fast
    in one pass; a stroke that cannot be timed gets its error in its place.

    Args:
        model: The arm whose joint limits the strokes keep.
        strokes: The strokes to time.
        tool_limits: The tool's velocity (m/s), acceleration (m/s^2) and jerk (m/s^3) limits
            along the path; a stroke's own speed caps the velocity.
        period: The controller's period, seconds: every duration is a multiple of it.

    Returns:
        One TimedStroke or KeympsError per stroke, in order.
    """
    rates = _StrokeRates(strokes)
    check_period = min(period, 1.0 / CHECK_RATE_HZ)
    limits = [
        Limits(min(stroke.speed, tool_limits.velocity), *_tail(tool_limits)) for stroke in strokes
    ]
    first: list[tuple[Any, float]] = [(None, 0.0)] * len(strokes)  # profile, duration
    out: list[TimedStroke | KeympsError | None] = [None] * len(strokes)
    pending = list(range(len(strokes)))
    for attempt in range(MAX_RETIMES):
        which, profiles, durations, failed = _profile_strokes(strokes, pending, limits, period)
        for k, error in failed:
            out[k] = error  # Ruckig's reason, kept: these are no longer pending
        pending = []
        if not which:
            break
        ratios = _check_profiles(model, rates, which, profiles, durations, check_period)
        for i, k in enumerate(which):
            if attempt == 0:
                first[k] = profiles[i], durations[i]
            v, a, j = (float(ratio[i]) for ratio in ratios)
            if max(v, a, j) <= 1.0:
                slowdown = durations[i] / first[k][1]
                out[k] = TimedStroke(strokes[k], profiles[i], durations[i], limits[k], slowdown)
            else:
                limits[k] = _lowered(limits[k], v, a, j, attempt)
                pending.append(k)
    for k in pending:
        out[k] = _untimeable(strokes[k])
    _place_stops(model, rates, out, first, check_period)
    return [item for item in out if item is not None]


def _profile_strokes(
    strokes: list[Stroke], pending: list[int], limits: list[Limits], period: float
) -> tuple[list[int], list[Any], list[float], list[tuple[int, KeympsError]]]:
    """The profiles of the pending strokes at their limits: the strokes profiled, their
    profiles and durations (s), and the strokes Ruckig could not profile with why."""
    which, profiles, durations, failed = [], [], [], []
    for k in pending:
        try:
            profile, duration = _profile(strokes[k].length, limits[k], period, strokes[k])
        except KeympsError as error:
            failed.append((k, error))
            continue
        which.append(k)
        profiles.append(profile)
        durations.append(duration)
    return which, profiles, durations, failed


def _lowered(limits: Limits, v: float, a: float, j: float, attempt: int) -> Limits:
    """The limits of the next try for a profile whose joints went v, a and j times over their
    velocity, acceleration and jerk limits (the largest ratio over the joints)."""
    if attempt < MAX_RETIMES // 2:  # lower only what is violated: keeps the profile fast
        return Limits(
            limits.velocity / max(v / LIMIT_MARGIN, 1.0),
            limits.acceleration / max(a / LIMIT_MARGIN, 1.0),
            limits.jerk / max(j / LIMIT_MARGIN, 1.0),
        )
    return limits.scaled(max(v, math.sqrt(a), j ** (1 / 3)) / LIMIT_MARGIN)


def _place_stops(
    model: RobotModel,
    rates: _StrokeRates,
    out: list[TimedStroke | KeympsError | None],
    first: list[tuple[Any, float]],
    check_period: float,
) -> None:
    """Set `worst_s` of each stroke slowed down enough to be stopped somewhere (_with_stops),
    from its `first` profile (at the tool limits) and that profile's duration."""
    slow = [
        k
        for k, item in enumerate(out)
        if isinstance(item, TimedStroke) and item.slowdown >= STOP_SLOWDOWN
    ]
    places = _worst_places(
        model,
        rates,
        slow,
        [first[k][0] for k in slow],
        [first[k][1] for k in slow],
        check_period,
    )
    for k, place in zip(slow, places, strict=True):
        out[k].worst_s = place  # type: ignore[union-attr]


def _untimeable(stroke: Stroke) -> KeympsError:
    return KeympsError(
        f"timing: piece {stroke.piece_index} ({stroke.kind}) cannot be timed inside the joint "
        "limits; the path passes too close to a singularity: move the base (task robot.base)"
    )


def _tail(limits: Limits) -> tuple[float, float]:
    return limits.acceleration, limits.jerk


def time_trajectory(
    model: RobotModel, tool_path: ToolPath, joint_path: JointPath, task: Task
) -> Trajectory:
    """Jerk-limited, joint-limit-respecting trajectory sampled at the controller rate."""
    from keymps.config.limits import check_timed_duration

    timed = time_strokes(model, tool_path, joint_path, task)
    check_timed_duration(sum(item.duration for item in timed), task)  # before sampling it
    rate = float(task.robot.rate_hz or model.rate_hz)
    trajectory = sample_trajectory(model, tool_path, timed, rate)
    slow = slow_piece_warnings(tool_path, timed, task.motion.work_speed)
    return dataclasses.replace(trajectory, warnings=tuple(slow)) if slow else trajectory


def slow_piece_warnings(
    tool_path: ToolPath, timed: list[TimedStroke], work_speed: float
) -> list[str]:
    """One line per work piece the joint limits slow SLOW_PIECE_FACTOR times or more."""
    lines = []
    by_piece: dict[int, list[TimedStroke]] = {}
    for item in timed:
        by_piece.setdefault(item.stroke.piece_index, []).append(item)
    for index, piece in enumerate(tool_path.pieces):
        if piece.kind != "work":
            continue
        mine = by_piece.get(index, [])
        duration = sum(item.duration for item in mine)
        at_tool_limits = sum(item.nominal for item in mine)
        if not mine or duration < SLOW_PIECE_FACTOR * at_tool_limits:
            continue
        length = sum(item.stroke.length for item in mine)
        worst = max(mine, key=lambda item: item.slowdown)
        where = ", ".join(f"{v:.3f}" for v in worst.stroke.points[len(worst.stroke.points) // 2])
        what = (
            f"work piece {piece.pair_index + 1}"
            if len(piece.piped_pairs) == 1
            else f"the stroke through {piece.pairs_label()}"
        )
        lines.append(
            f"{what} takes {duration:.1f} s, "
            f"{duration / at_tool_limits:.0f}x longer than at motion.work_speed "
            f"{work_speed:g} m/s (on average {1000 * length / duration:.1f} mm/s): the joints "
            f"cannot follow its path that fast near ({where}) m; a path with a sharp wiggle "
            "(a noisy demonstration: try --smooth) or near a singularity (move robot.base)"
        )
    return lines


def time_strokes(
    model: RobotModel, tool_path: ToolPath, joint_path: JointPath, task: Task
) -> list[TimedStroke]:
    """Each stroke timed on its own (they start and end at rest)."""
    rate = float(task.robot.rate_hz or model.rate_hz)
    tool_limits = Limits(math.inf, task.robot.max_tool_acceleration, task.robot.max_tool_jerk)
    timed = []
    strokes = split_strokes(model, tool_path, joint_path)
    for stroke, whole in zip(
        strokes, time_strokes_at_once(model, strokes, tool_limits, 1.0 / rate), strict=True
    ):
        if isinstance(whole, KeympsError):
            raise whole
        nominal = whole.duration / whole.slowdown
        parts = _with_stops(model, whole, tool_limits, 1.0 / rate, MAX_STOP_DEPTH)
        for part in parts:
            part.nominal = nominal * part.stroke.length / stroke.length
        timed.extend(parts)
    return timed


def _with_stops(
    model: RobotModel, whole: TimedStroke, tool_limits: Limits, period: float, depth: int
) -> list[TimedStroke]:
    """The stroke as timed whole or, when one place in it makes the joints slow all of it
    down, stopped at that place with each side timed on its own (whichever is faster)."""
    if whole.slowdown < STOP_SLOWDOWN or depth == 0:
        return [whole]
    halves = split_stroke(whole.stroke, whole.worst_s)
    if halves is None:
        return [whole]
    parts = []
    for timed in time_strokes_at_once(model, list(halves), tool_limits, period):
        if isinstance(timed, KeympsError):
            raise timed
        parts.extend(_with_stops(model, timed, tool_limits, period, depth - 1))
    return parts if sum(p.duration for p in parts) < whole.duration else [whole]


def sample_trajectory(
    model: RobotModel, tool_path: ToolPath, timed: list[TimedStroke], rate: float
) -> Trajectory:
    """Concatenate the strokes on one clock; every sample is on the controller's grid."""
    period = 1.0 / rate
    local = [
        np.arange(round(item.duration / period) + (1 if number == len(timed) - 1 else 0)) * period
        for number, item in enumerate(timed)
    ]
    s, sd, sdd = _sample_profiles([item.profile for item in timed], local)
    counts = [len(times) for times in local]
    q, qd, qdd = (np.empty((len(s), len(model.joint_names))) for _ in range(3))
    rates = _StrokeRates([item.stroke for item in timed])
    for part, q_part, qd_part, qdd_part in rates.chunks(
        list(range(len(timed))), s, counts, sd, sdd
    ):
        assert q_part is not None
        q[part], qd[part], qdd[part] = q_part.T, qd_part.T, qdd_part.T
    lengths = np.repeat([item.stroke.length for item in timed], counts)
    on_path = np.clip(s, 0.0, lengths)
    xyz = np.empty((len(s), 3))
    for item, start, count in zip(timed, np.cumsum(counts) - counts, counts, strict=True):
        part = slice(start, start + count)
        for k in range(3):  # the planned polyline at s, all strokes clipped in one call
            xyz[part, k] = np.interp(on_path[part], item.stroke.s, item.stroke.points[:, k])
    piece_index = np.repeat([item.stroke.piece_index for item in timed], counts).astype(int)

    kinds = np.array([tool_path.pieces[i].kind for i in range(len(tool_path.pieces))], dtype="<U6")
    trajectory = Trajectory(
        t=np.arange(len(s)) * period,
        q=q,
        qd=qd,
        qdd=qdd,
        tool_xyz=xyz,
        piece_index=piece_index,
        kind=kinds[piece_index],
        joint_names=model.joint_names,
        rate_hz=rate,
    )
    trajectory.qd[[0, -1]] = 0.0  # at rest; removes 1e-17 residues of the profile
    trajectory.qdd[[0, -1]] = 0.0
    return trajectory
