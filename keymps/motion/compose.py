"""Sequencing (Eq. 6): travel moves and re-targeted primitives composed into one tool path."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from keymps.errors import KeympsError
from keymps.motion.chains import Chain, pipe_chains
from keymps.motion.polyline import limit_along, rollout_along
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
BLADE_OVERLAP_M = 0.015
"""A cut longer than the blade is cut from both ends; the two strokes overlap this much."""
CHORD_END_M = 0.003
"""A cut's end this close inside its object's edge is on the edge (a chord may be cut either
way; the detected outline and a planner's ends differ by a few millimetres)."""


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
    join_distance: float = 0.0,
    blade_length: float = 0.0,
) -> ToolPath:
    """From `home`, per segment a travel piece (rise to object_top + clearance, move over,
    descend to the start) then a work piece (the primitive re-targeted to start/goal), and a
    last travel piece back to `home`. Every piece starts and ends at rest.

    Icing lines that meet are one continuous stroke (keymps.motion.chains): with an icing
    primitive and a fixed-yaw tool, pairs whose ends lie within `join_distance` (metres; 0:
    only ends that coincide) are piped as one work piece, the primitive run once along their
    polyline (keymps.motion.polyline), with no travel move between them; where they branch,
    each connected group is piped in as few strokes as it allows. Cuts and dots keep a piece
    per pair.

    yaw_mode 'follow' (a blade): the work piece's yaw is the segment's horizontal direction
    (radians, unwrapped: within half a turn of the cut before, the first cut's of `home_yaw`),
    so that the blade trails the tip; 'fixed' (a piping bag): yaw stays `home_yaw`. Yaw changes
    only while moving over, above the object. The blade (`blade_length` metres, 0: none) lies
    on the board only along a cut's end: a chord through more food is cut from both ends.

    `footprint` ((N, 2) board metres, the object's outline): work that would reach further
    outside it than the safety check allows (a sawing stroke overshooting a cut that ends just
    outside the object, as the prompts ask) is shortened smoothly near the cut's ends.
    With `objects` (several objects of their own heights), each travel piece rises to
    clearance above the tallest object its straight line passes over (the objects it leaves
    and reaches included) instead of above object_top.
    """
    home_arr = _finite_point(home, "home")
    _check_settings(object_top, clearance, work_speed, travel_speed, yaw_mode)
    _check_join(segments, join_distance)
    ends = _segment_ends(segments)
    outlines = {o.id: np.asarray(o.outline_m, dtype=float).reshape(-1, 2) for o in objects}
    single = np.asarray(footprint, dtype=float).reshape(-1, 2) if footprint is not None else None
    strokes, yaws = _strokes(
        segments, ends, primitive, yaw_mode, home_yaw, blade_length, join_distance, outlines, single
    )
    owners = [segments[c.pairs[0]].object_id for c in strokes]
    headings = yaws if yaw_mode == "follow" else [None] * len(yaws)
    work_paths = [
        _work_path(primitive, chain, work_speed, heading, outlines.get(owner, single))
        for chain, heading, owner in zip(strokes, headings, owners, strict=True)
    ]
    heights = _leg_heights(work_paths, owners, home_arr, objects, object_top, clearance)
    first_yaw = yaws[0] if yaw_mode == "follow" else home_yaw
    speeds = (float(work_speed), float(travel_speed))
    pieces = _pieces(strokes, owners, work_paths, yaws, heights, home_arr, first_yaw, speeds)
    return ToolPath(pieces=tuple(pieces), keyword=primitive.name)


def _segment_ends(segments: Sequence[Segment]) -> np.ndarray:
    """The pairs' (start, goal) points, (N, 2, 3) board metres; refuses a non-finite one."""
    return np.array(
        [
            [
                _finite_point(s.start, f"segment {k + 1} start"),
                _finite_point(s.goal, f"segment {k + 1} goal"),
            ]
            for k, s in enumerate(segments)
        ]
    )


def _strokes(
    segments: Sequence[Segment],
    ends: np.ndarray,
    primitive: Primitive,
    yaw_mode: str,
    home_yaw: float,
    blade_length: float,
    join_distance: float,
    outlines: Mapping[int, np.ndarray],
    single: np.ndarray | None,
) -> tuple[list[Chain], list[float]]:
    """The work strokes and their yaws: icing lines piped as chains, cuts one per pair (two
    for a chord longer than the blade)."""
    if primitive.family == "icing" and yaw_mode == "fixed":
        strokes = pipe_chains(ends, [s.object_id for s in segments], join_distance)
        return strokes, [home_yaw] * len(strokes)
    if yaw_mode == "follow":
        edges = [outlines.get(s.object_id, single) for s in segments]
        strokes, yaws = _blade_strokes(ends, edges, home_yaw)
        if blade_length <= 0:
            return strokes, yaws
        edges = [edges[c.pairs[0]] for c in strokes]
        return _from_both_ends(strokes, yaws, edges, blade_length, home_yaw)
    return [Chain((k,), (False,), ends[k]) for k in range(len(segments))], [home_yaw] * len(ends)


def _work_path(
    primitive: Primitive,
    chain: Chain,
    speed: float,
    heading: float | None,
    outline: np.ndarray | None,
) -> np.ndarray:
    """The work piece's points: the primitive re-targeted to the pair, or run once along the
    chain's polyline; kept near the outline's footprint margin when one is known."""
    usable = outline if outline is not None and len(outline) >= 3 else None
    start, goal = chain.vertices[0], chain.vertices[-1]
    if len(chain.pairs) > 1:
        reach = end_reaches(start, goal, usable) if usable is not None else (math.inf, math.inf)
        return rollout_along(
            primitive, chain.vertices, speed=speed, spacing=WORK_SPACING_M, reach=reach
        )
    # A plunge has no direction of its own: a blade's demo keeps the blade's yaw.
    points = primitive.rollout(start, goal, speed=speed, spacing=WORK_SPACING_M, heading=heading).y
    return points if usable is None else keep_strokes_near(points, start, goal, usable)


def _leg_heights(
    work_paths: Sequence[np.ndarray],
    owners: Sequence[int],
    home: np.ndarray,
    objects: Sequence[GroundedObject],
    object_top: float,
    clearance: float,
) -> list[float]:
    """Per travel leg (to each stroke's start, then home), the height it moves over at:
    clearance above object_top, or with `objects` above the tallest object it leaves, reaches
    or passes over."""
    if not objects:
        return [object_top + clearance] * (len(work_paths) + 1)
    by_id = {o.id: o for o in objects}
    starts = [home] + [points[-1] for points in work_paths]
    ends = [points[0] for points in work_paths] + [home]
    crossings = [_crossed_legs(starts, ends, o.outline_m) for o in objects]
    touching = list(zip([None, *owners], [*owners, None], strict=True))  # left, reached
    heights = []
    for leg, near in enumerate(touching):
        crossed = [by_id[i].height for i in near if i in by_id]
        crossed += [o.height for o, hit in zip(objects, crossings, strict=True) if hit[leg]]
        heights.append(max(crossed, default=0.0) + clearance)
    return heights


def _pieces(
    strokes: Sequence[Chain],
    owners: Sequence[int],
    work_paths: Sequence[np.ndarray],
    yaws: Sequence[float],
    heights: Sequence[float],
    home: np.ndarray,
    yaw: float,
    speeds: tuple[float, float],
) -> list[Piece]:
    """Travel to each stroke (at its leg's height), the stroke, and travel home."""
    work_speed, travel_speed = speeds
    pieces: list[Piece] = []
    position = home
    for chain, owner, points, work_yaw, height in zip(
        strokes, owners, work_paths, yaws, heights, strict=False
    ):
        first = chain.pairs[0]
        travel_points, travel_yaw = _travel(position, points[0], height, yaw, work_yaw)
        pieces.append(Piece("travel", first, travel_points, travel_yaw, travel_speed, owner))
        work_yaws = np.full(len(points), work_yaw)
        pieces.append(Piece("work", first, points, work_yaws, work_speed, owner, chain.pairs))
        position, yaw = points[-1], work_yaw
    travel_points, travel_yaw = _travel(position, home, heights[-1], yaw, yaw)
    last = strokes[-1].pairs[-1]
    pieces.append(Piece("travel", last, travel_points, travel_yaw, travel_speed, owners[-1]))
    return pieces


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
    axis = goal[:2] - start[:2]
    length = float(np.linalg.norm(axis))
    if length < NO_HEADING_M:
        return points
    direction = axis / length
    along = (points[:, :2] - start[:2]) @ direction
    reach_start, reach_goal = end_reaches(start, goal, outline)
    before, after = np.maximum(-along, 0.0), np.maximum(along - length, 0.0)
    if before.max() <= reach_start and after.max() <= reach_goal:
        return points
    limited = limit_along(along, length, reach_start, reach_goal)
    shifted = points.copy()
    shifted[:, :2] += (limited - along)[:, None] * direction
    return shifted


def end_reaches(start: np.ndarray, goal: np.ndarray, outline: np.ndarray) -> tuple[float, float]:
    """How far work may pass its start and its goal (board xy) and stay within the safety
    check's footprint margin, less FOOTPRINT_SLACK_M, of the outline."""
    from keymps.robot.safety import FOOTPRINT_MARGIN_M
    from keymps.robot.safety_geometry import outside_distance

    allowed = FOOTPRINT_MARGIN_M - FOOTPRINT_SLACK_M
    ends = outside_distance(np.array([start[:2], goal[:2]]), outline)
    reach_start, reach_goal = (max(0.0, allowed - float(d)) for d in ends)
    return reach_start, reach_goal


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


def _blade_strokes(
    ends: np.ndarray, outlines: Sequence[np.ndarray | None], home_yaw: float
) -> tuple[list[Chain], list[float]]:
    """Per cut its direction and the blade's yaw: the yaw is the direction of travel, so that
    the edge (along the tool's -x axis from the tip) trails the tip and sweeps the whole cut;
    a plunge keeps the yaw before it. A cut whose both ends lie on or beyond its object's
    edge (a chord) may be cut either way: it runs the way that turns the wrist least, its
    heights kept (it still starts above the food and ends on the board). A cut that ends
    inside the food (a ray to the centre) keeps its direction: reversed, the edge trailing
    from the rim would reach across the far side."""
    strokes: list[Chain] = []
    headings: list[float | None] = []
    previous: float | None = None
    for k, (start, goal) in enumerate(ends):
        delta = goal[:2] - start[:2]
        if float(np.hypot(*delta)) < NO_HEADING_M:
            strokes.append(Chain((k,), (False,), ends[k]))
            headings.append(None)
            continue
        heading = math.atan2(delta[1], delta[0])
        reverse = math.remainder(heading + math.pi, math.tau)
        if _is_chord(start, goal, outlines[k]) and _turn(reverse, previous, home_yaw) < _turn(
            heading, previous, home_yaw
        ):
            swapped = np.array([[*goal[:2], start[2]], [*start[:2], goal[2]]])
            strokes.append(Chain((k,), (True,), swapped))
            heading = reverse
        else:
            strokes.append(Chain((k,), (False,), ends[k]))
        # Unwrapped: the wrist turns the short way, never across +-180 degrees the long way.
        heading = _nearest_turn(heading, home_yaw if previous is None else previous)
        headings.append(heading)
        previous = heading
    held: float = next((h for h in headings if h is not None), home_yaw)
    yaws = []
    for maybe in headings:
        held = maybe if maybe is not None else held
        yaws.append(held)
    return strokes, yaws


def _from_both_ends(
    strokes: Sequence[Chain],
    yaws: Sequence[float],
    outlines: Sequence[np.ndarray | None],
    blade_length: float,
    home_yaw: float,
) -> tuple[list[Chain], list[float]]:
    """Each chord through more food than the blade lies along, as two strokes: the planned
    one, ending BLADE_OVERLAP_M / 2 past the middle, then one from the other end to as far
    short of it (its yaw turned half a turn, back towards `home_yaw`: the wrist never winds
    up). The strokes start above the food and end on the board as the planned one does.
    `outlines`: each stroke's object outline, or None."""
    kept: list[Chain] = []
    kept_yaws: list[float] = []
    for chain, yaw, outline in zip(strokes, yaws, outlines, strict=True):
        start, goal = chain.vertices[0], chain.vertices[-1]
        length = float(np.hypot(*(goal[:2] - start[:2])))
        through = _length_inside(start, goal, outline)
        if len(chain.pairs) > 1 or through <= blade_length or not _is_chord(start, goal, outline):
            kept.append(chain)
            kept_yaws.append(yaw)
            continue
        middle = 0.5 + 0.5 * BLADE_OVERLAP_M / length
        first = np.array([start, [*(start[:2] + middle * (goal[:2] - start[:2])), goal[2]]])
        second = np.array(
            [[*goal[:2], start[2]], [*(goal[:2] + middle * (start[:2] - goal[:2])), goal[2]]]
        )
        pair, backwards = chain.pairs[0], chain.reversed[0]
        kept += [Chain((pair,), (backwards,), first), Chain((pair,), (not backwards,), second)]
        kept_yaws += [yaw, yaw + math.copysign(math.pi, home_yaw - yaw)]
    return kept, kept_yaws


def _length_inside(start: np.ndarray, goal: np.ndarray, outline: np.ndarray | None) -> float:
    """How much of start-goal (board xy, metres) lies inside the outline (all of it without
    one), to a millimetre."""
    length = float(np.hypot(*(goal[:2] - start[:2])))
    if outline is None or len(outline) < 3 or length == 0.0:
        return length
    from keymps.robot.safety_geometry import inside_polygon

    steps = max(2, math.ceil(length / WORK_SPACING_M) + 1)
    samples = start[:2] + np.linspace(0.0, 1.0, steps)[:, None] * (goal[:2] - start[:2])
    return length * float(inside_polygon(samples, outline).mean())


def _turn(heading: float, previous: float | None, home_yaw: float) -> float:
    """How far the wrist turns from `previous` to `heading` (radians; from `home_yaw` for the
    first cut, which keeps the first cut's yaw near the arm's home orientation)."""
    return abs(math.remainder(heading - (home_yaw if previous is None else previous), math.tau))


def _nearest_turn(heading: float, reference: float) -> float:
    """`heading` plus the whole turns that bring it within half a turn of `reference`."""
    return reference + math.remainder(heading - reference, math.tau)


def _is_chord(start: np.ndarray, goal: np.ndarray, outline: np.ndarray | None) -> bool:
    """Whether both ends lie outside the outline or within CHORD_END_M inside its edge."""
    if outline is None or len(outline) < 3:
        return False
    from keymps.robot.safety_geometry import inside_polygon

    points = np.array([start[:2], goal[:2]])
    closed = np.vstack([outline, outline[:1]])
    a, b = closed[:-1], closed[1:]
    ab = b - a
    t = np.clip(
        np.einsum("pij,ij->pi", points[:, None] - a[None], ab) / np.maximum((ab**2).sum(1), 1e-18),
        0.0,
        1.0,
    )
    edge = np.linalg.norm(points[:, None] - (a[None] + t[..., None] * ab[None]), axis=2).min(1)
    inside = inside_polygon(points, outline)
    return bool(np.all(~inside | (edge <= CHORD_END_M)))


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


def _check_join(segments: Sequence[Segment], join_distance: float) -> None:
    if not segments:
        raise MotionError("compose: the plan has no keypoint pairs to execute")
    if not (math.isfinite(join_distance) and join_distance >= 0):
        raise MotionError(f"compose: join_distance must be metres >= 0, got {join_distance}")


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
