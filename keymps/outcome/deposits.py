"""Icing deposits: where a nozzle leaves icing, which deposits form one stroke, which merge.

A work piece deposits where the nozzle works within DEPOSIT_GAP_M of the object's top. Where it
stays in place, or moves less than a dot's diameter joined to no other deposit, it leaves a
dot: a disc
DOT_DIAMETER_FACTOR line widths across. Elsewhere it leaves a line: a band one line width wide
along its path. Deposits whose ends meet form one stroke; a stroke whose lines close on
themselves is a loop (a ring), and so is a line piped as one stroke that ends where it starts.
Two deposits merge where their icing touches, unless the drawing joins them there on purpose
(lines meeting at a corner or crossing, as a star's do).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from keymps.types import DepositEffect

DEPOSIT_GAP_M = 0.003
"""The nozzle deposits where it works at most this high above the object's top."""
DOT_DIAMETER_FACTOR = 2.0
"""A dot is this many line widths across: icing piped in place spreads to about twice the
nozzle's line (the sim executor's outcome.png draws dots so)."""
ON_TOP_SLACK_M = 0.001
"""A deposit is on the top surface when its icing stays inside the footprint to within this."""
JOIN_FACTOR = 0.5
"""Line ends closer than this many line widths are one joint of the drawing."""
SIMPLIFY_M = 0.0002
"""A line's path is kept to within this of the nozzle's."""
DOT_EXTENT_M = 0.001
"""A deposit whose path spans less than this is a dot (its pair's start is its end); any other
is a line, however short: joined to others, it is part of their stroke (a spiral's pieces)."""


@dataclass(frozen=True)
class Merge:
    """Two deposits whose icing runs together."""

    first: int
    second: int
    """Indices into the deposits."""
    gap_m: float
    """Distance of their centrelines (or centres) where they come closest."""
    needed_m: float
    """The distance at which they would just not touch."""
    kind: Literal["dots", "dot and line", "lines"]


def deposits_of(
    work: Sequence[tuple[int | tuple[int, ...], Any, np.ndarray]], line_width: float
) -> tuple[tuple[DepositEffect, ...], int, int]:
    """(deposits, strokes, loops) of the work pieces: each (its pair index, or the pair indices
    it pipes in order, its object (a keymps.outcome.predict.Food, or None), (n, 3) tip
    positions)."""
    placed: list[tuple[tuple[int, ...], Any, np.ndarray]] = []
    for pairs, food, tip in work:
        xy = _deposited(tip, food)
        if xy is not None:
            placed.append(((pairs,) if isinstance(pairs, int) else tuple(pairs), food, xy))
    blobs = _blobs([xy for _, _, xy in placed], line_width)
    shaped = [
        ("dot", xy.mean(axis=0, keepdims=True)) if blob else ("line", _simplified(xy))
        for (_, _, xy), blob in zip(placed, blobs, strict=True)
    ]
    tops = _tops([food for _, food, _ in placed], shaped, line_width)
    found = [
        (kind, pairs, food.id if food is not None else 0, path, top)
        for (pairs, food, _), (kind, path), top in zip(placed, shaped, tops, strict=True)
    ]
    stroke_of, loops = _strokes([(kind, path) for kind, _, _, path, _ in found], line_width)
    deposits = tuple(
        DepositEffect(
            kind,  # type: ignore[arg-type]
            pairs[0],
            object_id,
            path,
            (DOT_DIAMETER_FACTOR if kind == "dot" else 1.0) * line_width,
            stroke_of[k],
            on_top,
            pairs,
        )
        for k, (kind, pairs, object_id, path, on_top) in enumerate(found)
    )
    return deposits, len(set(stroke_of)), loops


def _deposited(tip: np.ndarray, food: Any) -> np.ndarray | None:
    """(n, 2) where a work piece's nozzle deposits (near the top), None where it does not."""
    top = float(food.height) if food is not None else 0.0
    near = tip[:, 2] - top <= DEPOSIT_GAP_M
    return tip[near, :2] if near.any() else None


def _blobs(paths: Sequence[np.ndarray], line_width: float) -> list[bool]:
    """Per deposit path, whether it is a dot: it stays in place (DOT_EXTENT_M), or spans less
    than a dot's diameter with neither end joined to another deposit (a dot piped slightly
    off its place is still a blob; a spiral's short pieces are joined lines)."""
    spans = [float(np.ptp(xy, axis=0).max()) for xy in paths]
    ends = np.array([xy[[0, -1]] for xy in paths]).reshape(-1, 2, 2)
    reach = JOIN_FACTOR * max(line_width, 1e-4)
    blobs = []
    for k, span in enumerate(spans):
        if span < DOT_EXTENT_M:
            blobs.append(True)
            continue
        others = np.delete(ends, k, axis=0).reshape(-1, 2)
        joined = (
            len(others)
            and float(np.linalg.norm(ends[k][:, None] - others[None], axis=2).min()) <= reach
        )
        blobs.append(span < DOT_DIAMETER_FACTOR * line_width and not joined)
    return blobs


def _simplified(xy: np.ndarray) -> np.ndarray:
    """The path (n, 2) with the points a straight line already passes near dropped. A path that
    ends where it starts is simplified in two halves, split at its point farthest from the
    start (Douglas-Peucker measures from the chord between the ends, which has none)."""
    import cv2

    far = int(np.argmax(np.linalg.norm(xy - xy[0], axis=1)))
    if len(xy) > 2 and 0 < far < len(xy) - 1 and np.linalg.norm(xy[-1] - xy[0]) < SIMPLIFY_M:
        return np.vstack([_simplified(xy[: far + 1])[:-1], _simplified(xy[far:])])
    scaled = (xy / SIMPLIFY_M).astype(np.float32).reshape(-1, 1, 2)
    kept = cv2.approxPolyDP(scaled, 1.0, False).reshape(-1, 2)
    return np.asarray(kept, dtype=float) * SIMPLIFY_M


def _tops(
    foods: Sequence[Any], shaped: Sequence[tuple[str, np.ndarray]], line_width: float
) -> list[bool]:
    """Per deposit, whether it lies on its object's top: the dots of an object tested at once."""
    tops = [False] * len(shaped)
    for food in {id(f): f for f in foods if f is not None}.values():
        mine = [k for k, f in enumerate(foods) if f is food]
        dots = [k for k in mine if shaped[k][0] == "dot"]
        if dots:
            centres = np.array([shaped[k][1][0] for k in dots])
            reach = DOT_DIAMETER_FACTOR * line_width / 2
            for k, top in zip(dots, _inside_by(centres, reach, food.outline_m), strict=True):
                tops[k] = bool(top)
        for k in mine:
            if shaped[k][0] == "line":
                tops[k] = _on_top(shaped[k][1], line_width / 2, food.outline_m)
    return tops


def _inside_by(points: np.ndarray, reach: float, outline: np.ndarray) -> np.ndarray:
    """(n,) whether each point is inside the polygon at least `reach` (less the slack) from
    its edge."""
    from keymps.robot.safety_geometry import distance_to_polyline, inside_polygon

    polygon = np.asarray(outline, float).reshape(-1, 2)
    closed = np.vstack([polygon, polygon[:1]])
    edge = distance_to_polyline(_lifted(points), _lifted(closed))
    return inside_polygon(points, polygon) & (edge >= reach - ON_TOP_SLACK_M)


def _on_top(path: np.ndarray, reach: float, outline: np.ndarray) -> bool:
    """Whether the icing `reach` either side of the path stays on the footprint."""
    return bool(_inside_by(_densified(path, max(reach, 0.0005)), reach, outline).all())


def _densified(path: np.ndarray, step: float) -> np.ndarray:
    """The path's points at most `step` apart (its corners kept)."""
    if len(path) == 1:
        return path
    pieces = [path[:1]]
    for a, b in zip(path[:-1], path[1:], strict=True):
        count = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        pieces.append(a + np.linspace(0.0, 1.0, count + 1)[1:, None] * (b - a))
    return np.concatenate(pieces)


def _lifted(xy: np.ndarray) -> np.ndarray:
    return np.column_stack([xy, np.zeros(len(xy))])


def _strokes(shapes: Sequence[tuple[str, np.ndarray]], line_width: float) -> tuple[list[int], int]:
    """Per deposit its stroke (0-based, in first-deposit order), and how many strokes close."""
    _, joint_of = _joints(shapes, line_width)
    parent = list(range(len(shapes)))

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    owners: dict[int, int] = {}
    for k, joints in enumerate(joint_of):
        for joint in joints:
            if joint in owners:
                parent[root(k)] = root(owners[joint])
            owners.setdefault(joint, k)
    roots = [root(k) for k in range(len(shapes))]
    numbering: dict[int, int] = {}
    stroke_of = [numbering.setdefault(r, len(numbering)) for r in roots]
    lines_of: dict[int, list[int]] = {}
    for k, (kind, _) in enumerate(shapes):
        if kind == "line":
            lines_of.setdefault(stroke_of[k], []).append(k)
    loops = 0
    for lines in lines_of.values():
        nodes = {j for k in lines for j in joint_of[k]}
        if len(lines) == 1:  # lines that meet, piped as one stroke (keymps.motion.chains)
            loops += len(nodes) == 1 and _encloses(shapes[lines[0]][1], line_width)
        else:
            loops += len(lines) >= 3 and len(lines) >= len(nodes)  # a cycle through its joints
    return stroke_of, loops


def _encloses(path: np.ndarray, line_width: float) -> bool:
    """Whether a line that ends where it starts closes around more than its own band: its
    area (shoelace) is over four square line widths (a line piped there and back is none)."""
    x, y = path[:, 0], path[:, 1]
    area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
    return area > 4.0 * line_width**2


def _joints(
    shapes: Sequence[tuple[str, np.ndarray]], line_width: float
) -> tuple[np.ndarray, list[tuple[int, ...]]]:
    """The drawing's joints (line ends within JOIN_FACTOR line widths are one), and per deposit
    the joints of its two ends (none for a dot)."""
    reach = JOIN_FACTOR * max(line_width, 1e-4)
    joints: list[np.ndarray] = []
    joint_of: list[tuple[int, ...]] = []
    for kind, path in shapes:
        if kind == "dot":
            joint_of.append(())
            continue
        mine = []
        for point in (path[0], path[-1]):
            near = [j for j, joint in enumerate(joints) if np.linalg.norm(joint - point) <= reach]
            if not near:
                joints.append(point)
                near = [len(joints) - 1]
            mine.append(near[0])
        joint_of.append(tuple(mine))
    return np.asarray(joints).reshape(-1, 2), joint_of


def merges(deposits: Sequence[DepositEffect], line_width: float) -> list[Merge]:
    """Every two deposits whose icing touches where the drawing does not join them, closest
    first: dots with dots and with lines by their discs, lines with lines by their bands
    (keymps.designs.legibility, joints and crossings excepted)."""
    if line_width <= 0 or not deposits:
        return []
    found = _dot_merges(deposits, line_width) + _line_merges(deposits, line_width)
    return sorted(found, key=lambda merge: merge.gap_m - merge.needed_m)


def _dot_merges(deposits: Sequence[DepositEffect], line_width: float) -> list[Merge]:
    """Dots closer than their discs allow to another dot, or to a line's band."""
    dots = [k for k, d in enumerate(deposits) if d.kind == "dot"]
    if not dots:
        return []
    centres = np.array([deposits[k].path_m[0] for k in dots])
    radius = np.array([deposits[k].width_m / 2 for k in dots])
    found: list[Merge] = []
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=2)
    needed = radius[:, None] + radius[None]
    for a, b in zip(*np.nonzero(np.triu(gaps < needed, k=1)), strict=True):
        found.append(Merge(dots[a], dots[b], float(gaps[a, b]), float(needed[a, b]), "dots"))
    for j, line in enumerate(deposits):
        if line.kind != "line":
            continue
        near = _distances(centres, line.path_m)
        for a in np.flatnonzero(near < radius + line.width_m / 2):
            needed_m = float(radius[a] + line.width_m / 2)
            pair = (min(dots[a], j), max(dots[a], j))
            found.append(Merge(*pair, float(near[a]), needed_m, "dot and line"))
    return found


def _line_merges(deposits: Sequence[DepositEffect], line_width: float) -> list[Merge]:
    from keymps.designs.legibility import merging_strokes

    lines = [k for k, d in enumerate(deposits) if d.kind == "line"]
    if len(lines) < 2:
        return []
    shapes = [("line", deposits[k].path_m) for k in lines]
    joints, joint_of = _joints(shapes, line_width)
    segments: list[np.ndarray] = []
    for k, ends in zip(lines, joint_of, strict=True):
        path = deposits[k].path_m.copy()
        path[0], path[-1] = joints[ends[0]], joints[ends[1]]  # joined ends meet exactly
        segments.extend(np.stack([path[:-1], path[1:]], axis=1))
    merge = merging_strokes(np.asarray(segments), line_width)
    if merge is None:
        return []
    gap, where = merge
    near = sorted(lines, key=lambda k: _distance(where, deposits[k].path_m))[:2]
    return [Merge(min(near), max(near), gap, line_width, "lines")]


def _distance(point: np.ndarray, path: np.ndarray) -> float:
    """Distance of a point to a polyline (or a single point)."""
    return float(_distances(np.asarray(point, float)[None], path)[0])


def _distances(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """(n,) distance of each point (n, 2) to a polyline (m, 2) (or a single point)."""
    if len(path) == 1:
        return np.linalg.norm(points - path[0], axis=1)
    a, b = path[:-1], path[1:]
    step = b - a
    lengths = np.maximum((step**2).sum(axis=1), 1e-18)
    t = np.clip(((points[:, None] - a[None]) * step[None]).sum(axis=2) / lengths, 0.0, 1.0)
    nearest = a[None] + t[:, :, None] * step[None]
    return np.linalg.norm(nearest - points[:, None], axis=2).min(axis=1)
