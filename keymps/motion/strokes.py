"""Cutting a tool path into strokes: the rest-to-rest parts the timing profiles one by one.

A piece is cut at its sharp corners; points of a dwell are dropped first; every stroke gets its
arc parameter s and a cubic spline q(s) through IK solutions at most MAX_KNOT_SPACING apart.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.errors import KeympsError
from keymps.types import JointPath, Piece, ToolPath

if TYPE_CHECKING:
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
MIN_STOP_GAP_M = 0.001
"""No stop closer than this to either end of a stroke (its ends are rests already)."""


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


def _parameter_steps(points: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(n-1, 4) steps in (x, y, z, YAW_RADIUS_M * yaw): the path parameter's geometry."""
    return np.column_stack([np.diff(points, axis=0), YAW_RADIUS_M * np.diff(yaw)])


TIE_M = 1e-9
"""Arc positions this close count as equally far (a nanometre: far above rounding, far below
any path's detail)."""


def _nearest_first(arc_m: list[float], first: int, last: int, middle: float) -> int:
    """Of points first..last, the first of those nearest to `middle`.

    A run of two corner points has both equally near its middle, up to the last bit of a sum;
    that bit differs between CPUs (NumPy's AVX-512 and AVX2 loops round differently), and the
    stroke must not end at another point on another machine."""
    nearest = min(abs(arc_m[k] - middle) for k in range(first, last + 1))
    return next(k for k in range(first, last + 1) if abs(arc_m[k] - middle) <= nearest + TIE_M)


def _geometry_of_all(
    parts: list[tuple[np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """(x, y, z, YAW_RADIUS_M * yaw) of all parts' points end to end, the length of every step
    between consecutive points (across parts too: not used) and where each part starts."""
    sizes = [len(points) for points, _ in parts]
    geometry = np.column_stack(
        [
            np.concatenate([points for points, _ in parts]),
            YAW_RADIUS_M * np.concatenate([yaw for _, yaw in parts]),
        ]
    )
    steps = np.linalg.norm(np.diff(geometry, axis=0), axis=1)
    return geometry, steps, (np.cumsum(sizes) - sizes).tolist()


def _corner_indexes_all(parts: list[tuple[np.ndarray, np.ndarray]]) -> list[list[int]]:
    """Point indexes where each (points, yaw) part turns sharper than CORNER_ANGLE_RAD.

    Directions are chords of at least CORNER_CHORD_M on each side of a point, so that the
    sub-millimetre jitter of a rollout turning round (the bottom of a dot) makes one corner,
    not many; of a run of neighbouring corner points the middle one is kept. Each part's arc
    length and chord search are its own; the directions of all points come in one pass.
    """
    if not parts:
        return []
    geometry, steps, starts = _geometry_of_all(parts)
    arcs, before, after = [], [], []
    for (points, _), start in zip(parts, starts, strict=True):
        n = len(points)
        arc = np.zeros(n)
        np.cumsum(steps[start : start + n - 1], out=arc[1:])
        arcs.append(arc)
        back = np.searchsorted(arc, arc - CORNER_CHORD_M, side="right") - 1
        ahead = np.searchsorted(arc, arc + CORNER_CHORD_M, side="left")
        before.append(np.maximum(back, 0) + start)  # back >= -1, ahead <= n: the clip
        after.append(np.minimum(ahead, n - 1) + start)
    incoming = geometry - geometry[np.concatenate(before)]
    outgoing = geometry[np.concatenate(after)] - geometry
    norms = np.linalg.norm(incoming, axis=1) * np.linalg.norm(outgoing, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.where(norms > 1e-18, (incoming * outgoing).sum(axis=1) / norms, 1.0)
    sharp_all = cosine < math.cos(CORNER_ANGLE_RAD)
    out: list[list[int]] = []
    for (points, _), start, arc in zip(parts, starts, arcs, strict=True):
        n = len(points)
        if n < 3 or arc[-1] <= 0:
            out.append([])
            continue
        at = (np.flatnonzero(sharp_all[start + 1 : start + n - 1]) + 1).tolist()  # no ends
        corners: list[int] = []
        if at:
            sharp, arc_m = set(at), arc.tolist()  # Python floats: the same arithmetic
            end = -1
            for index in at:
                if index <= end:
                    continue  # inside the run of the corner before
                end = index
                while end + 1 in sharp and arc_m[end + 1] - arc_m[index] <= 2 * CORNER_CHORD_M:
                    end += 1
                middle = (arc_m[index] + arc_m[end]) / 2  # a reversal's cluster: its tip
                corners.append(_nearest_first(arc_m, index, end, middle))
        out.append(corners)
    return out


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
    if model.closed_form is not None and parts:
        dense = _dense_points_all([(points, yaw) for points, yaw, _ in parts])
        # A part with nothing inserted keeps its points and joints as they are; it is solved
        # again only every few millimetres, to carry the branch from one part to the next.
        kept = [
            len(p) == len(points) for (p, _, _), (points, _, _) in zip(dense, parts, strict=True)
        ]
        carried = iter(
            _every_few_all([(p, y) for (p, y, _), same in zip(dense, kept, strict=True) if same])
        )
        solve = [
            next(carried) if same else np.arange(len(p))
            for (p, _, _), same in zip(dense, kept, strict=True)
        ]
        all_p = np.concatenate([p[i] for (p, _, _), i in zip(dense, solve, strict=True)])
        all_y = np.concatenate([y[i] for (_, y, _), i in zip(dense, solve, strict=True)])
        solved = model.solve_closed_form(all_p, all_y, parts[0][2][0])
        if solved is not None:
            sizes = np.array([len(i) for i in solve])
            offsets = np.cumsum(sizes) - sizes
            # Where the solve meets the path's own IK (the subset of a part with nothing
            # inserted, the original points of one with points inserted) it must agree:
            # otherwise it is not the path's branch.
            at = np.concatenate(
                [
                    offset + (np.arange(len(which)) if same else original)
                    for (_, _, original), which, same, offset in zip(
                        dense, solve, kept, offsets, strict=True
                    )
                ]
            )
            path_parts = [
                q[which] if same else q
                for (_, _, q), which, same in zip(parts, solve, kept, strict=True)
            ]
            path_q = np.concatenate(path_parts)
            deviation = np.abs(solved[0][at] - path_q).max(axis=1)
            rows = np.array([len(q) for q in path_parts])
            first_row = np.cumsum(rows) - rows
            if not np.any(np.maximum.reduceat(deviation, first_row) >= 1e-6):
                dense_q = solved[0]
                dense_q[at] = path_q
                return [
                    (points, yaw, q) if same else (p, y, dense_q[offset : offset + len(p)])
                    for (p, y, _), (points, yaw, q), same, offset in zip(
                        dense, parts, kept, offsets, strict=True
                    )
                ]
    return [_densify(model, points, yaw, q) for points, yaw, q in parts]


def _dense_points_all(
    parts: list[tuple[np.ndarray, np.ndarray]],
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """`_dense_points` of every (points, yaw) part, the same values: the gaps and the inserted
    points of all parts in one pass (the gap from one part's end to the next one's start
    left out)."""
    sizes = np.array([len(points) for points, _ in parts])
    points = np.concatenate([points for points, _ in parts])
    yaw = np.concatenate([yaw for _, yaw in parts])
    ends = np.cumsum(sizes) - 1  # each part's last point
    gaps = np.hypot(np.linalg.norm(np.diff(points, axis=0), axis=1), YAW_RADIUS_M * np.diff(yaw))
    extra = np.maximum(np.ceil(gaps / MAX_KNOT_SPACING).astype(int) - 1, 0)
    # every point but a part's last: its gap's start and `extra` evenly spaced inner points
    rows = np.append(extra + 1, 1)
    rows[ends] = 1
    gap_of = np.repeat(np.arange(len(points)), rows)
    starts = np.cumsum(rows) - rows
    inner = np.ones(len(points), dtype=bool)
    inner[ends] = False
    row_of_gap = gap_of[inner[gap_of]]
    fraction = (np.flatnonzero(inner[gap_of]) - starts[row_of_gap]) / rows[row_of_gap]
    dense_p = points[gap_of].copy()  # a part's last point as it is
    dense_y = yaw[gap_of].copy()
    step_p = points[row_of_gap + 1] - points[row_of_gap]
    dense_p[inner[gap_of]] = points[row_of_gap] + fraction[:, None] * step_p
    dense_y[inner[gap_of]] = yaw[row_of_gap] + fraction * (yaw[row_of_gap + 1] - yaw[row_of_gap])
    out = []
    first_point = ends + 1 - sizes
    for (part_p, part_y), start, end in zip(
        parts, first_point.tolist(), ends.tolist(), strict=True
    ):
        if not extra[start:end].any():
            out.append((part_p, part_y, np.arange(len(part_p))))
            continue
        begin, stop = starts[start], starts[end] + 1
        out.append((dense_p[begin:stop], dense_y[begin:stop], starts[start : end + 1] - begin))
    return out


def _every_few_all(parts: list[tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
    """Indexes of points about CARRY_SPACING_M apart along the path parameter of each (points,
    yaw) part (a turn of the tool counts as in `_parameter_steps`), both ends included; the
    arc parameters of all parts in one pass."""
    out = []
    for arc in _arc_parameters(parts):
        bins = np.floor(arc / CARRY_SPACING_M)
        keep = np.flatnonzero(np.diff(bins, prepend=-1.0) > 0)
        out.append(keep if keep[-1] == len(arc) - 1 else np.append(keep, len(arc) - 1))
    return out


CARRY_SPACING_M = 0.005
"""Points of a part with nothing inserted are re-solved this far apart (see _densify_all)."""


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


def _significant_points_all(parts: list[tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
    """Indexes of the points of each (points, yaw) part that move at least MIN_STEP_M from the
    last one kept (the steps of all parts in one pass).

    A rollout that dwells jitters; every wiggle would be a direction reversal of the path, a
    cusp the joints cannot follow at speed. Dropping those points moves the path by less than
    MIN_STEP_M.
    """
    if not parts:
        return []
    geometry, steps, starts = _geometry_of_all(parts)
    return [
        _significant_in(
            geometry[start : start + len(points)], steps[start : start + len(points) - 1]
        )
        for (points, _), start in zip(parts, starts, strict=True)
    ]


def _significant_in(geometry: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """`_significant_points_all` of one part's geometry and steps (see `_geometry_of_all`)."""
    n = len(geometry)
    # The test is the distance (1-D norm) from the last point kept. Row norms and sums of
    # squares in Python floats (other summation orders) decide only where they are clear of
    # MIN_STEP_M by far more than their rounding differences: runs of long steps are kept
    # whole, other points measured in Python floats; the 1-D norm itself decides the rest.
    low, high = MIN_STEP_M * (1 - 1e-9), MIN_STEP_M * (1 + 1e-9)
    low2, high2 = low * low, high * high
    unclear = [*np.flatnonzero(steps < high).tolist(), n - 1]  # steps not clearly long enough
    rows: list[list[float]] | None = None
    kept = [0]
    i = 1
    while i < n:
        last = kept[-1]
        if last == i - 1 and steps[i - 1] >= high:
            stop = unclear[bisect.bisect_left(unclear, i - 1)]
            kept.extend(range(i, stop + 1))  # each step from a point kept, each long enough
            i = stop + 1
            continue
        if rows is None:
            rows = geometry.tolist()
        x, y, z, w = rows[last]
        a, b, c, d = rows[i]
        squared = (a - x) ** 2 + (b - y) ** 2 + (c - z) ** 2 + (d - w) ** 2
        if squared >= high2 or (
            squared >= low2 and np.linalg.norm(geometry[i] - geometry[last]) >= MIN_STEP_M
        ):
            kept.append(i)
        i += 1
    if len(kept) == 1:
        return np.array(kept)  # a pure dwell: nothing for the timing to move along
    kept[-1] = n - 1
    return np.array(kept)


def split_strokes(model: RobotModel, tool_path: ToolPath, joint_path: JointPath) -> list[Stroke]:
    """Every piece cut at its sharp corners; parts that do not move are dropped."""
    from keymps.motion.spline import many_splines

    if len(joint_path.pieces) != len(tool_path.pieces):
        raise KeympsError(
            f"timing: the joint path has {len(joint_path.pieces)} pieces but the tool path "
            f"has {len(tool_path.pieces)}"
        )
    for index, (piece, q_all) in enumerate(zip(tool_path.pieces, joint_path.pieces, strict=True)):
        if len(q_all) != len(piece.points):
            raise KeympsError(
                f"timing: piece {index} has {len(piece.points)} points but {len(q_all)} joint "
                "vectors"
            )
    moving = []  # (piece index, kept point indexes) of the pieces that move
    for index, kept in enumerate(
        _significant_points_all([(piece.points, piece.yaw) for piece in tool_path.pieces])
    ):
        if len(kept) >= 2:
            moving.append((index, kept))
    kept_points = [
        (tool_path.pieces[i].points[kept], tool_path.pieces[i].yaw[kept]) for i, kept in moving
    ]
    parts: list[tuple[int, Piece, np.ndarray, np.ndarray, np.ndarray]] = []
    for (index, kept), (points, yaw), corners in zip(
        moving, kept_points, _corner_indexes_all(kept_points), strict=True
    ):
        piece, q = tool_path.pieces[index], joint_path.pieces[index][kept]
        cuts = [0, *corners, len(points) - 1]
        for start, end in zip(cuts[:-1], cuts[1:], strict=True):
            part = slice(start, end + 1)
            parts.append((index, piece, points[part], yaw[part], q[part]))
    dense = _densify_all(model, [(p, y, q) for _, _, p, y, q in parts])
    s_dense = _arc_parameters([(p, y) for p, y, _ in dense])
    s_plan = _arc_parameters([(p, y) for _, _, p, y, _ in parts])
    splines = many_splines(s_dense, [q for _, _, q in dense])
    strokes = [
        Stroke(index, piece.kind, s, points, spline, float(piece.speed))
        for (index, piece, points, _, _), s, spline in zip(parts, s_plan, splines, strict=True)
    ]
    if not strokes:
        raise KeympsError("timing: the tool path does not move")
    return strokes


def _arc_parameters(parts: list[tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
    """The arc parameter s (0 at the start) of every (points, yaw) part: the steps of all
    parts in one pass, each part's running sum on its own (the same sums as part by part)."""
    if not parts:
        return []
    sizes = [len(points) for points, _ in parts]
    steps = np.linalg.norm(
        _parameter_steps(
            np.concatenate([points for points, _ in parts]),
            np.concatenate([yaw for _, yaw in parts]),
        ),
        axis=1,
    )
    starts = np.cumsum(sizes) - sizes
    out = []
    for start, size in zip(starts.tolist(), sizes, strict=True):
        s = np.zeros(size)
        np.cumsum(steps[start : start + size - 1], out=s[1:])
        out.append(s)
    return out


def split_stroke(stroke: Stroke, at_s: float) -> tuple[Stroke, Stroke] | None:
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
        ShiftedPath(stroke.q_of_s, offset),
        stroke.speed,
    )
    return before, after


class ShiftedPath:
    """q(s + offset): the second part of a split stroke reuses its parent's spline.

    Args:
        q_of_s: The parent's joint path of its arc parameter s (a CubicSpline, or another
            ShiftedPath): `q_of_s(s, nu)`, `with_derivatives(s)` and `derivatives(s)`.
        offset: Where the part starts on the parent's s, metres.
    """

    def __init__(self, q_of_s: Any, offset: float):
        self.q_of_s, self.offset = q_of_s, offset

    def __call__(self, s: np.ndarray, nu: int = 0) -> np.ndarray:
        return self.q_of_s(np.asarray(s) + self.offset, nu)

    def with_derivatives(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.q_of_s.with_derivatives(np.asarray(s) + self.offset)

    def derivatives(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.q_of_s.derivatives(np.asarray(s) + self.offset)
