"""The intent's shapes: the pieces' shape (strips, wedges, squares, rounds) and the icing's
distance from the object's edge, held against the predicted pieces and deposits
(docs/outcome.md)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from keymps.outcome.directions import Shape, cut_angle, line_gap, measured_shape
from keymps.outcome.predict import Food
from keymps.outcome.verdict import (
    MIDDLE_FRACTION,
    ORIENTATION_TOLERANCE_DEG,
    PARALLEL_TOLERANCE_DEG,
    WIDTH_TOLERANCE_M,
    orientation_problems,
)
from keymps.types import CutEffect, DepositEffect, Effect, PieceEffect, PlanIntent

SQUARE_ASPECT = 1.25
"""A square piece's sides are within this ratio (the offline planner's grid of squares)."""
EDGE_DISTANCE_FRACTION = 0.1
"""The icing's distance from the edge: within this fraction of the stated one, and never closer
than WIDTH_TOLERANCE_M (the footprint is measured to half a pixel on either side)."""
HULL_SLACK_M = 0.0005
"""A deposit point this close to the convex hull of all of them belongs to the outer ring."""
SAMPLE_M = 0.001
"""Icing lines are measured every this many metres along their centreline."""

SHAPE_TOLERANCES: dict[str, float] = {
    "square_aspect": SQUARE_ASPECT,
    "edge_distance_fraction": EDGE_DISTANCE_FRACTION,
}
"""The numbers these checks add to keymps.outcome.verdict.TOLERANCES in run.json."""


def piece_shape_problems(effect: Effect, intent: PlanIntent, food: Food) -> list[str]:
    """What the cuts leave on `food` against the pieces' shape `intent` states."""
    cuts = [c for c in effect.cuts if c.object_id == food.id and len(c.severed_m)]
    pieces = [p for p in effect.pieces if p.object_id == food.id]
    if intent.piece_shape is None or not cuts:
        return []
    shape = measured_shape(food.outline_m)
    if intent.piece_shape == "strip":
        return _strip_problems(cuts, pieces, intent, shape)
    if intent.piece_shape == "wedge":
        return _wedge_problems(cuts, pieces, intent, food)
    if intent.piece_shape == "square":
        return _square_problems(pieces, intent)
    if intent.orientation is None:  # rounds: slices across a long object
        return orientation_problems(cuts, pieces, replace(intent, orientation="crosswise"), shape)
    return []


def _strip_problems(
    cuts: Sequence[CutEffect], pieces: Sequence[PieceEffect], intent: PlanIntent, shape: Shape
) -> list[str]:
    """Strips lie between parallel cuts, along a long object's length."""
    angles = [cut_angle(cut) for cut in cuts]
    spread = max(line_gap(a, angles[0]) for a in angles)
    if spread > math.radians(PARALLEL_TOLERANCE_DEG):
        return [
            f"the cuts are not parallel (they differ by up to {math.degrees(spread):.0f}°): they "
            f"leave {_sizes(pieces)}, not strips; the intent is {intent.describe()}"
        ]
    if shape.kind != "elongated" or intent.orientation is not None:
        return []
    off = max(line_gap(a, shape.axis) for a in angles)
    if off <= math.radians(ORIENTATION_TOLERANCE_DEG):
        return []
    return [
        f"the cuts run {math.degrees(off):.0f}° off the object's long axis: they leave "
        f"{_sizes(pieces)}, slices across it, not strips along it; the intent is "
        f"{intent.describe()}"
    ]


def _wedge_problems(
    cuts: Sequence[CutEffect], pieces: Sequence[PieceEffect], intent: PlanIntent, food: Food
) -> list[str]:
    """Wedges meet at the centre: every cut's line passes within MIDDLE_FRACTION of the
    object's extent of its centre."""
    outline = np.asarray(food.outline_m, float)
    centre = measured_shape(outline).centre
    size = float(np.ptp(outline, axis=0).max())
    for cut in cuts:
        ends = cut.severed_m.reshape(-1, 2)
        along = ends[-1] - ends[0]
        along = along / max(float(np.linalg.norm(along)), 1e-12)
        offset = centre - ends[0]
        miss = abs(float(offset[0] * along[1] - offset[1] * along[0]))
        if miss > MIDDLE_FRACTION * size:
            return [
                f"cut {cut.pair_index + 1} passes {1000 * miss:.1f} mm from the object's centre "
                f"(at most {1000 * MIDDLE_FRACTION * size:.1f} mm): the cuts leave "
                f"{_sizes(pieces)}, not wedges meeting at the centre; the intent is "
                f"{intent.describe()}"
            ]
    return []


def _square_problems(pieces: Sequence[PieceEffect], intent: PlanIntent) -> list[str]:
    for piece in pieces:
        long, short = _rectangle(piece.outline_m)
        if long > SQUARE_ASPECT * short:
            return [
                f"a piece is {1000 * long:.1f} x {1000 * short:.1f} mm, not a square (sides "
                f"within {SQUARE_ASPECT:g}:1); the cuts leave {_sizes(pieces)}; the intent is "
                f"{intent.describe()}"
            ]
    return []


def _rectangle(outline_m: np.ndarray) -> tuple[float, float]:
    """The sides (long, short) of the smallest rectangle around an outline, metres."""
    import cv2

    points = np.asarray(outline_m, np.float32).reshape(-1, 2)
    if len(points) < 3:
        return 0.0, 0.0
    _, (a, b), _ = cv2.minAreaRect(points)
    return float(max(a, b)), float(min(a, b))


def _sizes(pieces: Sequence[PieceEffect]) -> str:
    """'pieces of 120.0 x 40.1, ... mm' (the smallest rectangle around each)."""
    shown = [_rectangle(p.outline_m) for p in pieces[:8]]
    sizes = ", ".join(f"{1000 * a:.1f} x {1000 * b:.1f}" for a, b in shown)
    more = ", ..." if len(pieces) > 8 else ""
    return f"{len(pieces)} piece{'s' if len(pieces) != 1 else ''} of {sizes}{more} mm"


def edge_distance_problems(effect: Effect, intent: PlanIntent, food: Food) -> list[str]:
    """The outer ring of dots (or of icing lines, without dots) against the intent's distance
    from the object's edge: every deposit on the convex hull of all of them (the outer ring),
    and none nearer the edge than asked."""
    if intent.edge_distance_mm is None:
        return []
    mine = [d for d in effect.deposits if d.object_id == food.id]
    dots = [d for d in mine if d.kind == "dot"]
    ring = dots if dots and intent.rings is None else mine
    if not ring:
        return []
    points = np.concatenate([_samples(d) for d in ring])
    distance = _to_edge(points, food.outline_m)
    outer = distance[_on_hull(points)]
    wanted = intent.edge_distance_mm / 1000
    allowed = max(EDGE_DISTANCE_FRACTION * wanted, WIDTH_TOLERANCE_M)
    low, high = float(min(distance.min(), outer.min())), float(outer.max())
    if wanted - allowed <= low and high <= wanted + allowed:
        return []
    what = "dots lie" if ring is dots else "icing lies"
    return [
        f"the outer {what} {1000 * low:.1f} to {1000 * high:.1f} mm in from the object's "
        f"edge; the intent is {intent.describe()} (± {1000 * allowed:.1f} mm)"
    ]


def _samples(deposit: DepositEffect) -> np.ndarray:
    """(n, 2) a dot's centre, or points along a line's centreline every SAMPLE_M."""
    path = np.asarray(deposit.path_m, float).reshape(-1, 2)
    if len(path) == 1:
        return path
    pieces = [path[:1]]
    for a, b in zip(path[:-1], path[1:], strict=True):
        count = max(1, math.ceil(float(np.linalg.norm(b - a)) / SAMPLE_M))
        pieces.append(a + np.linspace(0.0, 1.0, count + 1)[1:, None] * (b - a))
    return np.concatenate(pieces)


def _to_edge(points: np.ndarray, outline_m: np.ndarray) -> np.ndarray:
    """(n,) each point's distance to the outline's boundary, metres."""
    from keymps.robot.safety_geometry import distance_to_polyline

    polygon = np.asarray(outline_m, float).reshape(-1, 2)
    closed = np.vstack([polygon, polygon[:1]])
    lifted = np.column_stack([points, np.zeros(len(points))])
    return distance_to_polyline(lifted, np.column_stack([closed, np.zeros(len(closed))]))


def _on_hull(points: np.ndarray) -> np.ndarray:
    """(n,) whether each point lies on (within HULL_SLACK_M of) the convex hull of them all."""
    import cv2

    if len(points) < 3:
        return np.ones(len(points), bool)
    hull = cv2.convexHull(points.astype(np.float64).astype(np.float32)).reshape(-1, 2)
    if len(hull) < 3:
        return np.ones(len(points), bool)
    inside = np.array(
        [cv2.pointPolygonTest(hull, (float(x), float(y)), True) for x, y in points], float
    )
    return np.asarray(inside <= HULL_SLACK_M)
