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
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.errors import KeympsError
from keymps.types import JointPath, Piece, ToolPath, Trajectory

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.robot.model import RobotModel

CORNER_ANGLE_RAD = math.radians(30.0)
"""A turn sharper than this between path segments stops the tool (a stroke ends there)."""
MIN_STEP_M = 3e-4
"""Path points closer than this to the previous one kept are dropped. A rollout that dwells (a
pause in a learned demonstration, the bottom of an icing dot) wanders back and forth by up to
about 0.2 mm; each wiggle is a reversal too short for the corner test, and one such cusp in
q(s) used to slow a whole 10 cm stroke to 1 mm/s."""
CORNER_CHORD_M = 0.0005
"""Path directions at a point are measured over chords at least this long."""
YAW_RADIUS_M = 0.05
"""Turning the tool by 1 rad counts like moving it 5 cm along the path parameter."""
MAX_KNOT_SPACING = 0.002
"""IK points are added wherever the tool path's points are further apart than this."""
CHECK_RATE_HZ = 1000.0
LIMIT_MARGIN = 0.98
"""Slowed-down strokes aim this far inside the violated limit."""
MAX_RETIMES = 12
STOP_SLOWDOWN = 1.5
"""A stroke the joint limits slow down this much is tried with a stop where it breaks them."""
MAX_STOP_DEPTH = 4
"""At most this many nested stops per stroke (up to 2**4 parts)."""
MIN_STOP_GAP_M = 0.001
"""No stop closer than this to either end of a stroke (its ends are rests already)."""
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
class Stroke:
    """A rest-to-rest part of one piece: the polyline, its arc parameter, q(s)."""

    piece_index: int
    kind: str
    s: np.ndarray
    points: np.ndarray
    q_of_s: Any
    """keymps.motion.spline.CubicSpline: (m,) s -> (m, 6) joints, with derivatives."""
    speed: float

    @property
    def length(self) -> float:
        return float(self.s[-1])


@dataclass
class TimedStroke:
    stroke: Stroke
    profile: Any
    """ruckig.Trajectory of s."""
    duration: float
    limits: Limits
    slowdown: float
    """Duration relative to the profile with the tool limits alone (1.0: no joint limit hit)."""
    worst_s: float = 0.0
    """Where (arc parameter) the profile at the tool limits broke the joint limits most."""
    nominal: float = 0.0
    """This stroke's share of the time the stroke it was split from takes at the tool limits
    alone (set by time_strokes)."""


def _parameter_steps(points: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(n-1, 4) steps in (x, y, z, YAW_RADIUS * yaw): the path parameter's geometry."""
    return np.column_stack([np.diff(points, axis=0), YAW_RADIUS_M * np.diff(yaw)])


def _corner_indexes(points: np.ndarray, yaw: np.ndarray) -> list[int]:
    """Point indexes where the path turns sharper than CORNER_ANGLE_RAD.

    Directions are chords of at least CORNER_CHORD_M on each side of a point, so that the
    sub-millimetre jitter of a rollout turning round (the bottom of a dot) makes one corner,
    not many; of a run of neighbouring corner points the middle one is kept.
    """
    geometry = np.column_stack([points, YAW_RADIUS_M * yaw])
    steps = np.linalg.norm(np.diff(geometry, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    n = len(points)
    if n < 3 or arc[-1] <= 0:
        return []
    before = np.searchsorted(arc, arc - CORNER_CHORD_M, side="right") - 1
    after = np.searchsorted(arc, arc + CORNER_CHORD_M, side="left")
    before, after = np.clip(before, 0, n - 1), np.clip(after, 0, n - 1)
    incoming = geometry - geometry[before]
    outgoing = geometry[after] - geometry
    norms = np.linalg.norm(incoming, axis=1) * np.linalg.norm(outgoing, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.where(norms > 1e-18, (incoming * outgoing).sum(axis=1) / norms, 1.0)
    sharp = cosine < math.cos(CORNER_ANGLE_RAD)
    sharp[[0, -1]] = False
    corners = []
    index = 0
    while index < n:
        if not sharp[index]:
            index += 1
            continue
        end = index
        while end + 1 < n and sharp[end + 1] and arc[end + 1] - arc[index] <= 2 * CORNER_CHORD_M:
            end += 1
        middle = (arc[index] + arc[end]) / 2  # a reversal's cluster is centred on its tip
        corners.append(index + int(np.argmin(np.abs(arc[index : end + 1] - middle))))
        index = end + 1
    return corners


def _dense_points(points: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points and yaws with evenly spaced points inserted wherever consecutive points are more
    than MAX_KNOT_SPACING apart, and the indexes of the original points among them."""
    gaps = np.hypot(np.linalg.norm(np.diff(points, axis=0), axis=1), YAW_RADIUS_M * np.diff(yaw))
    extra = np.maximum(np.ceil(gaps / MAX_KNOT_SPACING).astype(int) - 1, 0)
    if not extra.any():
        return points, yaw, np.arange(len(points))
    # Every gap g contributes its start and `extra[g]` evenly spaced inner points.
    per_gap = extra + 1
    gap_of = np.repeat(np.arange(len(gaps)), per_gap)
    starts = np.cumsum(per_gap) - per_gap
    fraction = (np.arange(len(gap_of)) - starts[gap_of]) / per_gap[gap_of]
    dense_p = np.vstack(
        [points[gap_of] + fraction[:, None] * (points[gap_of + 1] - points[gap_of]), points[-1:]]
    )
    dense_y = np.append(yaw[gap_of] + fraction * (yaw[gap_of + 1] - yaw[gap_of]), yaw[-1])
    return dense_p, dense_y, np.append(starts, len(dense_p) - 1)


def _densify_all(
    model: RobotModel, parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]]
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """`_densify` of every (points, yaw, q) part; with the closed form, all the inserted points
    of the path in one solve (consecutive parts join up, so one branch runs through them)."""
    dense = [_dense_points(points, yaw) for points, yaw, _ in parts]
    if model.closed_form is not None and parts:
        all_p = np.concatenate([p for p, _, _ in dense])
        all_y = np.concatenate([y for _, y, _ in dense])
        solved = model._solve_closed_form(all_p, all_y, parts[0][2][0])
        if solved is not None:
            ends = np.cumsum([len(p) for p, _, _ in dense])[:-1]
            out = []
            for (p, y, original), (_, _, q), dense_q in zip(
                dense, parts, np.split(solved[0], ends), strict=True
            ):
                if np.abs(dense_q[original] - q).max() >= 1e-6:  # not the path's branch
                    break
                dense_q[original] = q
                out.append((p, y, dense_q))
            else:
                return out
    return [_densify(model, points, yaw, q) for points, yaw, q in parts]


def _densify(
    model: RobotModel, points: np.ndarray, yaw: np.ndarray, q: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Insert IK-solved points where consecutive points are more than MAX_KNOT_SPACING apart."""
    dense_p, dense_y, original = _dense_points(points, yaw)
    if len(dense_p) == len(points):
        return points, yaw, q
    if model.closed_form is not None:
        dense_q, _, _ = model.solve_points(dense_p, dense_y, q[0], where="timing")
        if np.abs(dense_q[original] - q).max() < 1e-6:  # the same branch as the path's IK
            dense_q[original] = q
            return dense_p, dense_y, dense_q
    return _densify_iterative(model, points, yaw, q)


def _densify_iterative(
    model: RobotModel, points: np.ndarray, yaw: np.ndarray, q: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`_densify` gap by gap, each gap's inner points solved from the IK at its start."""
    out_p, out_y, out_q = [points[:1]], [yaw[:1]], [q[:1]]
    for i in range(1, len(points)):
        gap = math.hypot(
            float(np.linalg.norm(points[i] - points[i - 1])),
            YAW_RADIUS_M * float(yaw[i] - yaw[i - 1]),
        )
        extra = math.ceil(gap / MAX_KNOT_SPACING) - 1
        if extra > 0:
            fractions = np.linspace(0, 1, extra + 2)[1:-1]
            inner_p = points[i - 1] + fractions[:, None] * (points[i] - points[i - 1])
            inner_y = yaw[i - 1] + fractions * (yaw[i] - yaw[i - 1])
            inner_q, _, _ = model.solve_points(
                inner_p, inner_y, q[i - 1], where="timing", method="iterative"
            )
            out_p.append(inner_p)
            out_y.append(inner_y)
            out_q.append(inner_q)
        out_p.append(points[i : i + 1])
        out_y.append(yaw[i : i + 1])
        out_q.append(q[i : i + 1])
    return np.concatenate(out_p), np.concatenate(out_y), np.concatenate(out_q)


def _significant_points(points: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Indexes of the points that move at least MIN_STEP_M from the last one kept.

    A rollout that dwells jitters; every wiggle would be a direction reversal of the path, a
    cusp the joints cannot follow at speed. Dropping those points moves the path by less than
    MIN_STEP_M.
    """
    geometry = np.column_stack([points, YAW_RADIUS_M * yaw])
    kept = [0]
    for i in range(1, len(points)):
        if np.linalg.norm(geometry[i] - geometry[kept[-1]]) >= MIN_STEP_M:
            kept.append(i)
    if len(kept) == 1:
        return np.array(kept)  # a pure dwell: nothing for the timing to move along
    kept[-1] = len(points) - 1
    return np.array(kept)


def split_strokes(model: RobotModel, tool_path: ToolPath, joint_path: JointPath) -> list[Stroke]:
    """Every piece cut at its sharp corners; parts that do not move are dropped."""
    from keymps.motion.spline import CubicSpline

    if len(joint_path.pieces) != len(tool_path.pieces):
        raise KeympsError(
            f"timing: the joint path has {len(joint_path.pieces)} pieces but the tool path "
            f"has {len(tool_path.pieces)}"
        )
    parts: list[tuple[int, Piece, np.ndarray, np.ndarray, np.ndarray]] = []
    for index, (piece, q_all) in enumerate(zip(tool_path.pieces, joint_path.pieces, strict=True)):
        if len(q_all) != len(piece.points):
            raise KeympsError(
                f"timing: piece {index} has {len(piece.points)} points but {len(q_all)} joint "
                "vectors"
            )
        kept = _significant_points(piece.points, piece.yaw)
        if len(kept) < 2:
            continue
        points, yaw, q = piece.points[kept], piece.yaw[kept], q_all[kept]
        cuts = [0, *_corner_indexes(points, yaw), len(points) - 1]
        for start, end in zip(cuts[:-1], cuts[1:], strict=True):
            part = slice(start, end + 1)
            parts.append((index, piece, points[part], yaw[part], q[part]))
    dense = _densify_all(model, [(p, y, q) for _, _, p, y, q in parts])
    strokes = []
    for (index, piece, points, yaw, _), (dense_p, dense_yaw, dense_q) in zip(
        parts, dense, strict=True
    ):
        s_dense = np.concatenate(
            [[0.0], np.cumsum(np.linalg.norm(_parameter_steps(dense_p, dense_yaw), axis=1))]
        )
        s_plan = np.concatenate(
            [[0.0], np.cumsum(np.linalg.norm(_parameter_steps(points, yaw), axis=1))]
        )
        strokes.append(
            Stroke(
                index,
                piece.kind,
                s_plan,
                points,
                CubicSpline(s_dense, dense_q),
                float(piece.speed),
            )
        )
    if not strokes:
        raise KeympsError("timing: the tool path does not move")
    return strokes


def _profile(length: float, limits: Limits, period: float) -> tuple[Any, float]:
    """Rest-to-rest Ruckig profile of s over `length`, its duration a multiple of `period`."""
    from ruckig import InputParameter, Result, Ruckig
    from ruckig import Trajectory as RuckigTrajectory

    request = InputParameter(1)
    request.current_position = [0.0]
    request.target_position = [length]
    request.max_velocity = [limits.velocity]
    request.max_acceleration = [limits.acceleration]
    request.max_jerk = [limits.jerk]
    generator = Ruckig(1)
    profile = RuckigTrajectory(1)
    result = generator.calculate(request, profile)
    if result not in (Result.Working, Result.Finished):
        raise KeympsError(f"timing: Ruckig could not time a stroke of {length:.4f} m ({result})")
    rounded = math.ceil(profile.duration / period - 1e-9) * period
    if rounded - profile.duration > 1e-12:
        request.minimum_duration = rounded
        result = generator.calculate(request, profile)
        if result not in (Result.Working, Result.Finished):
            raise KeympsError(f"timing: Ruckig could not stretch a stroke to {rounded:.3f} s")
    return profile, rounded


def _sample_profile(profile: Any, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration of a 1-DOF Ruckig profile at `times`.

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


def _sample_profile_by_calls(
    profile: Any, times: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The same with one Ruckig call per time (the reference the numpy version is tested on)."""
    values = np.array([[v[0] for v in profile.at_time(float(t))] for t in times])
    return values[:, 0], values[:, 1], values[:, 2]


def _joint_motion(
    stroke: Stroke, s: np.ndarray, sd: np.ndarray, sdd: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, q dot, q double dot from q(s) and the timing of s (chain rule)."""
    s = np.clip(s, 0.0, stroke.length)
    q, dq, ddq = stroke.q_of_s.with_derivatives(s)
    return q, dq * sd[:, None], ddq * (sd**2)[:, None] + dq * sdd[:, None]


def _limit_ratios(
    model: RobotModel, qd: np.ndarray, qdd: np.ndarray, period: float
) -> tuple[float, float, float]:
    """The largest |qd|/limit, |qdd|/limit, |jerk|/limit (jerk by differences of qdd)."""
    velocity = float((np.abs(qd) / model.velocity_limits).max())
    acceleration = float((np.abs(qdd) / model.acceleration_limits).max())
    jerk = np.diff(qdd, axis=0) / period if len(qdd) > 1 else np.zeros((1, 6))
    return velocity, acceleration, float((np.abs(jerk) / model.jerk_limits).max())


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


def time_stroke(
    model: RobotModel, stroke: Stroke, tool_limits: Limits, period: float
) -> TimedStroke:
    """The fastest profile (tool limits first) whose joints stay inside every joint limit."""
    limits = Limits(min(stroke.speed, tool_limits.velocity), *_tail(tool_limits))
    check_period = min(period, 1.0 / CHECK_RATE_HZ)
    first_duration = None
    worst_s = 0.0
    for attempt in range(MAX_RETIMES):
        profile, duration = _profile(stroke.length, limits, period)
        times = np.arange(0.0, duration + 0.5 * check_period, check_period)
        times[-1] = min(times[-1], duration)
        s, sd, sdd = _sample_profile(profile, times)
        _, qd, qdd = _joint_motion(stroke, s, sd, sdd)
        if first_duration is None:
            first_duration = duration
            worst_s = _worst_place(model, s, qd, qdd, check_period)
        rv, ra, rj = _limit_ratios(model, qd, qdd, check_period)
        if max(rv, ra, rj) <= 1.0:
            return TimedStroke(
                stroke, profile, duration, limits, duration / first_duration, worst_s
            )
        if attempt < MAX_RETIMES // 2:
            # lower only what is violated: keeps the profile fast where it can be
            limits = Limits(
                limits.velocity / max(rv / LIMIT_MARGIN, 1.0),
                limits.acceleration / max(ra / LIMIT_MARGIN, 1.0),
                limits.jerk / max(rj / LIMIT_MARGIN, 1.0),
            )
        else:
            limits = limits.scaled(max(rv, math.sqrt(ra), rj ** (1 / 3)) / LIMIT_MARGIN)
    raise KeympsError(
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
    for index, piece in enumerate(tool_path.pieces):
        if piece.kind != "work":
            continue
        mine = [item for item in timed if item.stroke.piece_index == index]
        duration = sum(item.duration for item in mine)
        at_tool_limits = sum(item.nominal for item in mine)
        if not mine or duration < SLOW_PIECE_FACTOR * at_tool_limits:
            continue
        length = sum(item.stroke.length for item in mine)
        worst = max(mine, key=lambda item: item.slowdown)
        where = ", ".join(f"{v:.3f}" for v in worst.stroke.points[len(worst.stroke.points) // 2])
        lines.append(
            f"work piece {piece.pair_index + 1} takes {duration:.1f} s, "
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
    for stroke in split_strokes(model, tool_path, joint_path):
        whole = time_stroke(model, stroke, tool_limits, 1.0 / rate)
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
    halves = _split_stroke(whole.stroke, whole.worst_s)
    if halves is None:
        return [whole]
    parts = []
    for half in halves:
        timed = time_stroke(model, half, tool_limits, period)
        parts.extend(_with_stops(model, timed, tool_limits, period, depth - 1))
    return parts if sum(p.duration for p in parts) < whole.duration else [whole]


def _split_stroke(stroke: Stroke, at_s: float) -> tuple[Stroke, Stroke] | None:
    """The stroke cut at its plan point nearest to `at_s`; None when that is at an end."""
    index = int(np.argmin(np.abs(stroke.s - at_s)))
    if not 0 < index < len(stroke.s) - 1:
        return None
    offset = float(stroke.s[index])
    if min(offset, stroke.length - offset) < MIN_STOP_GAP_M:
        return None
    before = Stroke(
        stroke.piece_index,
        stroke.kind,
        stroke.s[: index + 1].copy(),
        stroke.points[: index + 1],
        stroke.q_of_s,
        stroke.speed,
    )
    after = Stroke(
        stroke.piece_index,
        stroke.kind,
        stroke.s[index:] - offset,
        stroke.points[index:],
        _Shifted(stroke.q_of_s, offset),
        stroke.speed,
    )
    return before, after


class _Shifted:
    """q(s + offset): the second part of a split stroke reuses its parent's spline."""

    def __init__(self, q_of_s: Any, offset: float):
        self.q_of_s, self.offset = q_of_s, offset

    def __call__(self, s: np.ndarray, nu: int = 0) -> np.ndarray:
        return self.q_of_s(np.asarray(s) + self.offset, nu)


def sample_trajectory(
    model: RobotModel, tool_path: ToolPath, timed: list[TimedStroke], rate: float
) -> Trajectory:
    """Concatenate the strokes on one clock; every sample is on the controller's grid."""
    period = 1.0 / rate
    parts_t, parts_q, parts_qd, parts_qdd, parts_xyz, parts_piece = [], [], [], [], [], []
    offset = 0
    for number, item in enumerate(timed):
        steps = round(item.duration / period)
        last = number == len(timed) - 1
        local = np.arange(steps + (1 if last else 0)) * period
        s, sd, sdd = _sample_profile(item.profile, local)
        q, qd, qdd = _joint_motion(item.stroke, s, sd, sdd)
        parts_t.append((offset + np.arange(len(local))) * period)
        parts_q.append(q)
        parts_qd.append(qd)
        parts_qdd.append(qdd)
        parts_xyz.append(_planned_points(item.stroke, s))
        parts_piece.append(np.full(len(local), item.stroke.piece_index))
        offset += steps
    piece_index = np.concatenate(parts_piece).astype(int)
    kinds = np.array([tool_path.pieces[i].kind for i in range(len(tool_path.pieces))], dtype="<U6")
    trajectory = Trajectory(
        t=np.concatenate(parts_t),
        q=np.concatenate(parts_q),
        qd=np.concatenate(parts_qd),
        qdd=np.concatenate(parts_qdd),
        tool_xyz=np.concatenate(parts_xyz),
        piece_index=piece_index,
        kind=kinds[piece_index],
        joint_names=model.joint_names,
        rate_hz=rate,
    )
    trajectory.qd[[0, -1]] = 0.0  # at rest; removes 1e-17 residues of the profile
    trajectory.qdd[[0, -1]] = 0.0
    return trajectory


def _planned_points(stroke: Stroke, s: np.ndarray) -> np.ndarray:
    """The tool path's polyline at arc parameter s (what the tool should be doing)."""
    s = np.clip(s, 0.0, stroke.length)
    return np.column_stack([np.interp(s, stroke.s, stroke.points[:, k]) for k in range(3)])
