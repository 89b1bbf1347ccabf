"""Sequencing (Eq. 6): travel moves and re-targeted primitives composed into one tool path."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from keymps.errors import KeympsError
from keymps.primitives.dictionary import Primitive
from keymps.types import GroundedObject, Piece, Segment, ToolPath

WORK_SPACING_M = 0.001
"""Work pieces are sampled at least this finely (the re-targeted rollout's points)."""
TRAVEL_SPACING_M = 0.01
"""Travel legs are straight lines; a point every centimetre is plenty for IK and checks."""
TURN_STEP_RAD = math.radians(5.0)
"""A turn in place is sampled at least this finely."""
NO_HEADING_M = 0.001
"""Segments with less horizontal travel than this (dots, plunges) keep the previous yaw."""
FOOTPRINT_SLACK_M = 0.002
"""Strokes near a cut's ends stop this far inside the safety check's footprint margin."""


class MotionError(KeympsError):
    """The segments or motion settings cannot be composed into a tool path."""


def compose_tool_path(
    segments: Sequence[Segment],
    primitive: Primitive,
    *,
    object_top: float,
    clearance: float,
    work_speed: float,
    travel_speed: float,
    yaw_mode: str,
    home: np.ndarray,
    home_yaw: float = 0.0,
    footprint: np.ndarray | None = None,
    objects: Sequence[GroundedObject] = (),
) -> ToolPath:
    """From `home`, per segment a travel piece (rise to object_top + clearance, move over,
    descend to the start) then a work piece (the primitive re-targeted to start/goal), and a
    last travel piece back to `home`. Every piece starts and ends at rest.

    yaw_mode 'follow' (a blade): the work piece's yaw is the segment's horizontal direction
    (within +-180 degrees), so that the blade trails the tip: a yaw taken modulo 180 degrees let
    the edge lead, and the first fifth of a cut was left uncut; 'fixed' (a piping bag): yaw stays
    `home_yaw`. Yaw changes only while moving over, above the object.

    `footprint` ((N, 2) board metres, the object's outline): work that would reach further
    outside it than the safety check allows (a sawing stroke overshooting a cut that ends just
    outside the object, as the prompts ask) is shortened smoothly near the cut's ends.
    With `objects` (several objects of their own heights), each travel piece rises to
    clearance above the tallest object its straight line passes over (the objects it leaves
    and reaches included) instead of above object_top.
    """
    home_arr = _finite_point(home, "home")
    _check_settings(object_top, clearance, work_speed, travel_speed, yaw_mode)
    if not segments:
        raise MotionError("compose: the plan has no keypoint pairs to execute")
    travel_z = object_top + clearance
    pieces: list[Piece] = []
    yaws = _work_yaws(segments, yaw_mode, home_yaw)
    work_paths = [
        primitive.rollout(
            _finite_point(seg.start, f"segment {k + 1} start"),
            _finite_point(seg.goal, f"segment {k + 1} goal"),
            speed=work_speed,
            spacing=WORK_SPACING_M,
            # A plunge has no direction of its own: a blade's demo keeps the blade's yaw.
            heading=yaws[k] if yaw_mode == "follow" else None,
        ).y
        for k, seg in enumerate(segments)
    ]
    outlines = {o.id: np.asarray(o.outline_m, dtype=float).reshape(-1, 2) for o in objects}
    if footprint is not None or outlines:
        single = (
            np.asarray(footprint, dtype=float).reshape(-1, 2) if footprint is not None else None
        )
        work_paths = [
            keep_strokes_near(
                points,
                np.asarray(seg.start, float),
                np.asarray(seg.goal, float),
                outline,  # each cut's own object's outline, with several objects
            )
            if (outline := outlines.get(seg.object_id, single)) is not None and len(outline) >= 3
            else points
            for points, seg in zip(work_paths, segments, strict=True)
        ]
    position, yaw = home_arr, yaws[0] if yaw_mode == "follow" else home_yaw
    by_id = {o.id: o for o in objects}
    here: int | None = None  # the object the tool is over (None: home)
    # travel leg k ends at work piece k's start; the last one goes home
    leg_starts = [home_arr] + [points[-1] for points in work_paths]
    leg_ends = [points[0] for points in work_paths] + [home_arr]
    crossings = [_crossed_legs(leg_starts, leg_ends, o.outline_m) for o in objects]

    def leg_z(leg: int, ends: tuple[int | None, int | None]) -> float:
        if not by_id:
            return travel_z
        crossed = [by_id[i].height for i in ends if i in by_id]
        crossed += [o.height for o, hit in zip(objects, crossings, strict=True) if hit[leg]]
        return max(crossed, default=0.0) + clearance

    for index, (points, work_yaw) in enumerate(zip(work_paths, yaws, strict=True)):
        owner = segments[index].object_id
        z = leg_z(index, (here, owner))
        travel_points, travel_yaw = _travel(position, points[0], z, yaw, work_yaw)
        pieces.append(Piece("travel", index, travel_points, travel_yaw, float(travel_speed), owner))
        pieces.append(
            Piece("work", index, points, np.full(len(points), work_yaw), float(work_speed), owner)
        )
        position, yaw, here = points[-1], work_yaw, owner
    z = leg_z(len(segments), (here, None))
    travel_points, travel_yaw = _travel(position, home_arr, z, yaw, yaw)
    pieces.append(
        Piece(
            "travel", len(segments) - 1, travel_points, travel_yaw, float(travel_speed),
            segments[-1].object_id,
        )
    )  # fmt: skip
    return ToolPath(pieces=tuple(pieces), keyword=primitive.name)


def keep_strokes_near(
    points: np.ndarray, start: np.ndarray, goal: np.ndarray, outline: np.ndarray
) -> np.ndarray:
    """The work path with its reach beyond the cut's ends limited so that it stays within the
    safety check's footprint margin (less FOOTPRINT_SLACK_M) of the outline.

    Along the cut, each end may be passed by `reach` = margin - slack - (how far that end is
    already outside the object): distance to the outline grows at most as fast as the path
    moves, so that bound holds. Overshoot beyond an end is mapped through reach * tanh(d /
    reach), identity to second order at the end: strokes there become shorter, smoothly.
    Paths already within reach are returned unchanged.
    """
    from keymps.robot.safety import FOOTPRINT_MARGIN_M
    from keymps.robot.safety_geometry import outside_distance

    axis = goal[:2] - start[:2]
    length = float(np.linalg.norm(axis))
    if length < NO_HEADING_M:
        return points
    direction = axis / length
    along = (points[:, :2] - start[:2]) @ direction
    allowed = FOOTPRINT_MARGIN_M - FOOTPRINT_SLACK_M
    ends = outside_distance(np.array([start[:2], goal[:2]]), outline)
    reach_start, reach_goal = (max(0.0, allowed - float(d)) for d in ends)
    before, after = np.maximum(-along, 0.0), np.maximum(along - length, 0.0)
    if before.max() <= reach_start and after.max() <= reach_goal:
        return points
    limited = along.copy()
    limited[along < 0] = -_soft_limit(before[along < 0], reach_start)
    limited[along > length] = length + _soft_limit(after[along > length], reach_goal)
    shifted = points.copy()
    shifted[:, :2] += (limited - along)[:, None] * direction
    return shifted


def _soft_limit(distance: np.ndarray, reach: float) -> np.ndarray:
    """reach * tanh(distance / reach): about `distance` when small, never beyond `reach`."""
    if reach <= 0.0:
        return np.zeros_like(distance)
    return reach * np.tanh(distance / reach)


def _leg_samples(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Points along a-b (board xy) at most half the travel spacing apart, ends included."""
    a, b = np.asarray(a, float)[:2], np.asarray(b, float)[:2]
    length = float(np.linalg.norm(b - a))
    count = max(2, math.ceil(length / (TRAVEL_SPACING_M / 2)) + 1)
    return a + np.linspace(0.0, 1.0, count)[:, None] * (b - a)


def _crossed_legs(
    starts: Sequence[np.ndarray], ends: Sequence[np.ndarray], outline: np.ndarray
) -> np.ndarray:
    """Per leg starts[k]-ends[k] (board xy), whether it passes over the polygon or within the
    travel spacing of it: one distance pass over all legs' samples."""
    from keymps.robot.safety_geometry import outside_distance

    samples = [_leg_samples(a, b) for a, b in zip(starts, ends, strict=True)]
    first = np.cumsum([0] + [len(points) for points in samples[:-1]])
    near = outside_distance(np.concatenate(samples), np.asarray(outline, float))
    return np.logical_or.reduceat(near <= TRAVEL_SPACING_M, first)


def _work_yaws(segments: Sequence[Segment], yaw_mode: str, home_yaw: float) -> list[float]:
    """Per segment, the tool yaw during its work piece: a blade's is the segment's heading, the
    tool x axis along the travel, so that the edge (along -x from the tip) trails the tip and
    sweeps the whole cut; a plunge keeps the yaw before it."""
    if yaw_mode == "fixed":
        return [home_yaw] * len(segments)
    headings = []
    for segment in segments:
        delta = np.asarray(segment.goal, float)[:2] - np.asarray(segment.start, float)[:2]
        headings.append(
            math.atan2(delta[1], delta[0]) if np.hypot(*delta) >= NO_HEADING_M else None
        )
    previous = next((h for h in headings if h is not None), home_yaw)
    yaws = []
    for heading in headings:
        previous = heading if heading is not None else previous
        yaws.append(previous)
    return yaws


def _travel(
    start: np.ndarray, end: np.ndarray, travel_z: float, start_yaw: float, end_yaw: float
) -> tuple[np.ndarray, np.ndarray]:
    """Rise to travel_z (if below), move over at or above it, descend to end (if below).

    Every point of the over-move is at or above travel_z, so it cannot cross the object. The
    yaw turns only up there: along the over-move, or in place when the move is too short."""
    above_start = np.array([start[0], start[1], max(start[2], travel_z)])
    above_end = np.array([end[0], end[1], max(end[2], travel_z)])
    over_is_short = float(np.linalg.norm(above_end - above_start)) < 1e-3
    turn = (above_start, above_start, start_yaw, end_yaw) if over_is_short else None
    legs = [
        (start, above_start, start_yaw, start_yaw),
        *([turn] if turn is not None else []),
        (above_start, above_end, end_yaw if over_is_short else start_yaw, end_yaw),
        (above_end, end, end_yaw, end_yaw),
    ]
    points, yaws = [start[None, :]], [np.array([start_yaw])]
    for a, b, yaw_a, yaw_b in legs:
        length = float(np.linalg.norm(b - a))
        rotation = abs(yaw_b - yaw_a)
        if length < 1e-12 and rotation < 1e-12:
            continue
        count = max(1, math.ceil(length / TRAVEL_SPACING_M), math.ceil(rotation / TURN_STEP_RAD))
        fractions = np.linspace(0.0, 1.0, count + 1)[1:]
        points.append(a + fractions[:, None] * (b - a))
        turning = yaw_a + fractions * (yaw_b - yaw_a)
        turning[-1] = yaw_b  # exactly: a rounded end would count as a turn during the descent
        yaws.append(turning)
    if len(points) == 1:  # already there: a zero-length piece of two identical points
        points.append(end[None, :])
        yaws.append(np.array([end_yaw]))
    return np.vstack(points), np.concatenate(yaws)


def _finite_point(value: object, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise MotionError(f"compose: {name} must be a finite [x, y, z] point, got {value!r}")
    return arr


def _check_settings(
    object_top: float, clearance: float, work_speed: float, travel_speed: float, yaw_mode: str
) -> None:
    for name, value in (("object_top", object_top), ("clearance", clearance)):
        if not math.isfinite(value) or value < 0:
            raise MotionError(
                f"compose: {name} must be a non-negative number of metres, got {value}"
            )
    for name, value in (("work_speed", work_speed), ("travel_speed", travel_speed)):
        if not math.isfinite(value) or value <= 0:
            raise MotionError(f"compose: {name} must be a positive number of m/s, got {value}")
    if yaw_mode not in ("follow", "fixed"):
        raise MotionError(f"compose: yaw mode {yaw_mode!r} is not 'follow' or 'fixed'")
