"""The verdict: a predicted effect held against what the plan claims (docs/outcome.md).

Every plan is checked for what is never right: a cut that misses the food, never cuts through
it, or stops short of its edge (an end inside the food that meets no other cut); icing that
leaves nothing, lies off the top surface, or merges with other icing. What the intents state is
checked as well: the number of pieces and whether they are equal, the cuts' direction in the
object's own frame, slice widths, a cut through the middle, the dots and rings.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from keymps.outcome.deposits import DOT_DIAMETER_FACTOR, merges
from keymps.outcome.directions import Shape, cut_angle, line_gap, measured_shape
from keymps.outcome.predict import PARTING_M, Food, line_inside
from keymps.types import CutEffect, Effect, PieceEffect, PlanIntent

END_TOLERANCE_M = PARTING_M
"""A cut's end inside the food counts as at the edge, or on another cut, within this."""
ORIENTATION_TOLERANCE_DEG = 5.0
"""A cut runs in the stated direction when within this of it (a VLM's keypoints a few pixels
off turn a 15 cm cut by 1-2 degrees; the issue's turned cake was 10 degrees off)."""
ALIGNED_DEG = 10.0
"""An object whose own axes are within this of the image's is aligned with the image: its cuts
may run along either frame ("vertically" of a loaf lying across the image; a bent or tapered
object's measured axis is a few degrees off its true one)."""
PARALLEL_TOLERANCE_DEG = 3.0
"""Cuts whose directions differ by less than this are parallel (pieces compared by width)."""
WIDTH_TOLERANCE_M = 0.0015
"""Slice widths: within the intent's fraction of the width, and never closer than this (the
footprint is measured to about half a pixel, 0.25-0.5 mm, on either side)."""
SLICE_WIDTH_FRACTION = 0.1
"""Slices of a stated width: each within this fraction of it."""
OVERCUT_M = 0.01
"""A cut may run this far past another one it crosses before it ends inside the food: a slit
(a ray turned a little past the centre), not a cut that stops short."""
MIDDLE_FRACTION = 0.05
"""One cut through the middle: within this fraction of the object's extent of its middle."""

TOLERANCES: dict[str, float] = {
    "cut_end_m": END_TOLERANCE_M,
    "overcut_m": OVERCUT_M,
    "orientation_deg": ORIENTATION_TOLERANCE_DEG,
    "aligned_deg": ALIGNED_DEG,
    "parallel_deg": PARALLEL_TOLERANCE_DEG,
    "width_m": WIDTH_TOLERANCE_M,
    "slice_width_fraction": SLICE_WIDTH_FRACTION,
    "middle_fraction": MIDDLE_FRACTION,
    "dot_diameter_line_widths": DOT_DIAMETER_FACTOR,
}
"""The numbers the checks use, recorded in run.json (outcome.tolerances); the equal-parts
tolerance is each intent's own `equal` (Appendix F: 0.05)."""


def cut_problems(effect: Effect, foods: Sequence[Food], blade_length: float = 0.0) -> list[str]:
    """What is wrong with the cuts whatever was asked: each cut must go through the food, down
    to the board, and from edge to edge (or to another cut)."""
    problems: list[str] = []
    by_id = {food.id: food for food in foods}
    for cut in effect.cuts:
        food = by_id[cut.object_id]
        name = f"cut {cut.pair_index + 1}"
        if cut.length_m <= 0 and cut.depth_m <= 0:
            problems.append(
                f"{name} never goes below the object's top, {1000 * food.height:.1f} mm above "
                "the board (scene.object_height): it cuts nothing"
            )
        elif cut.length_m <= 0:
            problems.append(f"{name} misses the food: its edge passes beside the object")
        elif len(cut.severed_m) == 0:
            above = 1000 * (food.height - cut.depth_m)
            problems.append(
                f"{name} runs {1000 * cut.length_m:.1f} mm into the food but cuts through it "
                + (
                    f"nowhere: the edge stays {above:.1f} mm above the board"
                    if above > 1.0
                    else "nowhere: the edge reaches the board only outside the object"
                )
            )
        else:
            short = _short_end(cut, food, effect.cuts)
            if short is not None:
                chord = cut.chord_m or 0.0
                longer = (
                    f" (the {1000 * blade_length:.0f} mm blade, robot.tool.blade_length, lies on "
                    "the board along the end of a cut only)"
                    if 0 < blade_length < chord - END_TOLERANCE_M
                    else ""
                )
                problems.append(
                    f"{name} stops {1000 * short:.1f} mm short of the object's edge: it cuts "
                    f"through {1000 * cut.severed_length_m:.1f} of the {1000 * chord:.1f} mm "
                    f"across{longer}"
                )
    return problems


def _short_end(cut: CutEffect, food: Food, cuts: Sequence[CutEffect]) -> float | None:
    """How far the first end of the cut's severed stretches that lies inside the food, on no
    other cut and not just past one (OVERCUT_M), is from the object's edge along the cut's line
    (None: every end is fine)."""
    others = [c.severed_m for c in cuts if c is not cut and c.object_id == cut.object_id]
    lines = np.concatenate(others).reshape(-1, 2, 2) if others else np.zeros((0, 2, 2))
    for start, end in cut.severed_m:
        length = max(float(np.linalg.norm(end - start)), 1e-12)
        axis = (end - start) / length
        inside = line_inside(food.outline_m, start, axis)
        crossings = _crossings(start, end, lines) * length
        for point, t in ((start, 0.0), (end, length)):
            holding = inside[(inside[:, 0] <= t + 1e-9) & (t - 1e-9 <= inside[:, 1])]
            if not len(holding):
                continue  # the end lies outside the food
            to_edge = float(min(t - holding[0, 0], holding[0, 1] - t))
            if to_edge <= END_TOLERANCE_M:
                continue
            if len(lines) and _distance_to_segments(point, lines) <= END_TOLERANCE_M:
                continue
            if len(crossings) and float(np.abs(crossings - t).min()) <= OVERCUT_M:
                continue  # a slit just past another cut: the pieces part there
            return to_edge
    return None


def _crossings(start: np.ndarray, end: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Where (fractions of start-end) the segment start-end crosses each of `segments`."""
    if not len(segments):
        return np.zeros(0)
    d = end - start
    a, b = segments[:, 0], segments[:, 1]
    e = b - a
    denominator = d[0] * e[:, 1] - d[1] * e[:, 0]
    usable = np.abs(denominator) > 1e-15
    gap = a - start
    t = np.where(
        usable, (gap[:, 0] * e[:, 1] - gap[:, 1] * e[:, 0]) / np.where(usable, denominator, 1), -1
    )
    u = np.where(
        usable, (gap[:, 0] * d[1] - gap[:, 1] * d[0]) / np.where(usable, denominator, 1), -1
    )
    hit = usable & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    return t[hit]


def _distance_to_segments(point: np.ndarray, segments: np.ndarray) -> float:
    a, b = segments[:, 0], segments[:, 1]
    step = b - a
    t = np.clip(((point - a) * step).sum(axis=1) / np.maximum((step**2).sum(axis=1), 1e-18), 0, 1)
    return float(np.linalg.norm(a + t[:, None] * step - point, axis=1).min())


def intent_problems(effect: Effect, intent: PlanIntent, food: Food) -> list[str]:
    """What the cuts leave on `food` against what `intent` states about it."""
    cuts = [c for c in effect.cuts if c.object_id == food.id and len(c.severed_m)]
    pieces = [p for p in effect.pieces if p.object_id == food.id]
    shape = measured_shape(food.outline_m)
    problems: list[str] = []
    if intent.pieces is not None and len(pieces) != intent.pieces:
        problems.append(
            f"the cuts leave {len(pieces)} piece{'s' if len(pieces) != 1 else ''} "
            f"({_shares(pieces)} of the object); the intent is {intent.describe()}"
        )
    if intent.orientation is not None and cuts:
        problems += orientation_problems(cuts, pieces, intent, shape)
    if problems:
        return problems
    if intent.equal is not None and intent.pieces is not None:
        check = _equal_widths if _equal_by(intent, shape) == "width" else _equal_areas
        problems += check(cuts, pieces, intent, food)
    if intent.slice_width_mm is not None and cuts:
        problems += _width_problems(cuts, intent, food)
    if intent.design == "middle" and len(cuts) == 1:
        problems += _middle_problems(cuts[0], food)
    return problems


def _equal_by(intent: PlanIntent, shape: Shape) -> str:
    """What equal pieces compare when the intent does not say: widths across the cuts for an
    elongated object's slices and a round one's parallel slices (the eval's ground truth),
    areas otherwise (wedges, grids, a square's slices: equal widths along its sides are equal
    areas, and a square cut askew is not in equal parts)."""
    if intent.equal_by is not None:
        return intent.equal_by
    if shape.kind == "elongated" or (shape.kind == "round" and intent.design == "parallel"):
        return "width"
    return "area"


def _shares(pieces: Sequence[PieceEffect]) -> str:
    shares = sorted((100 * p.share for p in pieces), reverse=True)
    shown = ", ".join(f"{s:.0f} %" for s in shares[:12])
    return shown + (", ..." if len(shares) > 12 else "") if shares else "none"


def _equal_areas(
    cuts: Sequence[CutEffect], pieces: Sequence[PieceEffect], intent: PlanIntent, food: Food
) -> list[str]:
    assert intent.pieces is not None and intent.equal is not None
    ideal = 1.0 / intent.pieces
    worst = max(abs(p.share - ideal) / ideal for p in pieces)
    if worst <= intent.equal:
        return []
    areas = ", ".join(f"{1e4 * p.area_m2:.1f}" for p in pieces[:12])
    return [
        f"the cuts leave pieces of {_shares(pieces)} of the object ({areas} cm²), the worst "
        f"{100 * worst:.0f} % off an equal share; the intent is {intent.pieces} equal pieces "
        f"(each {100 * ideal:.1f} % ± {100 * intent.equal:g} % of it)"
    ]


def _equal_widths(
    cuts: Sequence[CutEffect], pieces: Sequence[PieceEffect], intent: PlanIntent, food: Food
) -> list[str]:
    assert intent.pieces is not None and intent.equal is not None
    slicing = _slicing(cuts, food)
    if isinstance(slicing, str):
        return [f"{slicing}; the intent is {intent.describe()}"]
    widths = slicing
    ideal = float(widths.sum()) / intent.pieces
    allowed = max(intent.equal * ideal, WIDTH_TOLERANCE_M)
    if float(np.abs(widths - ideal).max()) <= allowed:
        return []
    shown = ", ".join(f"{100 * w:.1f}" for w in widths[:12])
    return [
        f"the cuts leave slices {shown} cm wide; the intent is {intent.pieces} equal slices "
        f"({100 * ideal:.1f} cm ± {1000 * allowed:.1f} mm)"
    ]


def _slicing(cuts: Sequence[CutEffect], food: Food) -> np.ndarray | str:
    """The widths (m) of the slices parallel cuts leave, from the low end of the object across
    them; or what stops them being slices."""
    angles = [cut_angle(cut) for cut in cuts]
    spread = max(line_gap(a, angles[0]) for a in angles)
    if spread > math.radians(PARALLEL_TOLERANCE_DEG):
        return f"the cuts are not parallel (they differ by up to {math.degrees(spread):.0f}°)"
    mean = angles[0] + float(np.mean([math.remainder(a - angles[0], math.pi) for a in angles]))
    across = np.array([-math.sin(mean), math.cos(mean)])
    extent = np.asarray(food.outline_m, float) @ across
    positions = sorted(
        float(np.mean(cut.severed_m.reshape(-1, 2), axis=0) @ across) for cut in cuts
    )
    edges = np.array([float(extent.min()), *positions, float(extent.max())])
    return np.diff(edges)


def _width_problems(cuts: Sequence[CutEffect], intent: PlanIntent, food: Food) -> list[str]:
    assert intent.slice_width_mm is not None
    slicing = _slicing(cuts, food)
    if isinstance(slicing, str):
        return [f"{slicing}; the intent is {intent.describe()}"]
    measured = float(slicing.sum())
    wanted = intent.slice_width_mm / 1000
    if intent.object_length_mm:
        wanted *= measured / (intent.object_length_mm / 1000)  # the user's length is the scale
    allowed = max(SLICE_WIDTH_FRACTION * wanted, WIDTH_TOLERANCE_M)
    for widths in (slicing, slicing[::-1]):  # slices from either end
        full = widths[:-1] if len(widths) > 1 else widths
        if float(np.abs(full - wanted).max()) <= allowed:
            return []
    shown = ", ".join(f"{100 * w:.1f}" for w in slicing[:12])
    return [
        f"the cuts leave slices {shown} cm wide; the intent is slices {100 * wanted:.1f} cm "
        f"wide (± {1000 * allowed:.1f} mm) from one end"
    ]


def _middle_problems(cut: CutEffect, food: Food) -> list[str]:
    angle = cut_angle(cut)
    across = np.array([-math.sin(angle), math.cos(angle)])
    extent = np.asarray(food.outline_m, float) @ across
    middle = (float(extent.min()) + float(extent.max())) / 2
    at = float(np.mean(cut.severed_m.reshape(-1, 2), axis=0) @ across)
    size = float(extent.max() - extent.min())
    if abs(at - middle) <= MIDDLE_FRACTION * size:
        return []
    return [
        f"the cut runs {1000 * abs(at - middle):.1f} mm from the middle of the object "
        f"({100 * abs(at - middle) / size:.0f} % of its {100 * size:.1f} cm); the intent is one "
        "cut through the middle"
    ]


def orientation_problems(
    cuts: Sequence[CutEffect], pieces: Sequence[PieceEffect], intent: PlanIntent, shape: Shape
) -> list[str]:
    """The first cut that runs off the direction `intent.orientation` states, as one problem.

    Args:
        cuts: The cuts through the object (each with severed stretches).
        pieces: The pieces they leave (named in the problem).
        intent: What the plan states; its orientation picks the wanted directions.
        shape: The object's measured frame.

    Returns:
        No problem, or one naming the cut, how far off it runs (degrees) and the pieces.
    """
    wanted = _wanted_directions(intent, shape)
    if not wanted:
        return []
    tolerance = math.radians(ORIENTATION_TOLERANCE_DEG)
    for cut in cuts:
        off = min(line_gap(cut_angle(cut), direction) for direction in wanted)
        if off > tolerance:
            areas = ", ".join(f"{1e4 * p.area_m2:.1f}" for p in pieces[:12])
            left = f": pieces of {areas} cm² ({_shares(pieces)})" if len(pieces) > 1 else ""
            return [
                f"cut {cut.pair_index + 1} runs {math.degrees(off):.1f}° off the "
                f"{_axis_name(intent, shape)} (at most {ORIENTATION_TOLERANCE_DEG:g}°){left}; "
                f"the intent is {intent.describe()}"
            ]
    return []


def _axis_name(intent: PlanIntent, shape: Shape) -> str:
    if intent.orientation in ("lengthwise", "crosswise"):
        return "object's long axis" if intent.orientation == "lengthwise" else "object's cross axis"
    if shape.kind == "round":
        return f"image's {intent.orientation}"
    return f"object's own side nearest the image's {intent.orientation}"


def _wanted_directions(intent: PlanIntent, shape: Shape) -> list[float]:
    """The directions the cuts may run in (radians, board frame): "vertical" / "horizontal" is
    the object's own side nearest the image's vertical / horizontal; for an object within
    ALIGNED_DEG of the image's axes the image's direction too. None where the object's frame
    fixes nothing (lengthwise on a round or square object)."""
    axes = (shape.axis, shape.axis + math.pi / 2)
    if intent.orientation in ("vertical", "horizontal"):
        image = math.pi / 2 if intent.orientation == "vertical" else 0.0
        own = min(axes, key=lambda a: line_gap(a, image))
        aligned = line_gap(own, image) <= math.radians(ALIGNED_DEG)
        return [image, own] if aligned else [own]
    if shape.kind != "elongated" or intent.orientation is None:
        return []
    return [axes[0] if intent.orientation == "lengthwise" else axes[1]]


def icing_problems(effect: Effect, work_pairs: Sequence[int], line_width: float) -> list[str]:
    """What is wrong with the icing whatever was asked: every icing pair deposits on the top
    surface, and no two deposits run together."""
    problems: list[str] = []
    deposited = {pair for d in effect.deposits for pair in d.piped_pairs}
    empty = [p + 1 for p in work_pairs if p not in deposited]
    if empty:
        problems.append(
            f"icing pair{'s' if len(empty) > 1 else ''} {_list(empty)} deposit{'' if len(empty) > 1 else 's'} "
            "nothing: the nozzle never comes near the top surface"
        )
    off = [d for d in effect.deposits if not d.on_top]
    if off:
        problems.append(
            f"{len(off)} deposit{'s lie' if len(off) > 1 else ' lies'} off the top surface "
            f"(pair{'s' if len(off) > 1 else ''} {_list([d.pair_index + 1 for d in off])})"
        )
    merging = merges(effect.deposits, line_width)
    if merging:
        first = merging[0]
        a, b = effect.deposits[first.first], effect.deposits[first.second]
        what = {"dots": "dots", "dot and line": "a dot and a line", "lines": "lines"}[first.kind]
        problems.append(
            f"the icing merges: {what} of pairs {a.pair_index + 1} and {b.pair_index + 1} come "
            f"{1000 * first.gap_m:.1f} mm apart and need {1000 * first.needed_m:.1f} mm not to "
            f"touch (a {1000 * line_width:g} mm line, dots {DOT_DIAMETER_FACTOR:g} lines across)"
            + (f"; {len(merging)} such places" if len(merging) > 1 else "")
        )
    return problems


def icing_intent_problems(effect: Effect, intent: PlanIntent, food: Food) -> list[str]:
    mine = [d for d in effect.deposits if d.object_id == food.id]
    dots = sum(d.kind == "dot" for d in mine)
    problems = []
    if intent.dots is not None and dots != intent.dots:
        problems.append(f"the icing has {dots} dots; the intent is {intent.describe()}")
    if intent.rings is not None and effect.loops != intent.rings:
        problems.append(
            f"the icing has {effect.loops} closed line{'s' if effect.loops != 1 else ''}; the "
            f"intent is {intent.describe()}"
        )
    return problems


def _list(numbers: Sequence[int]) -> str:
    shown = ", ".join(str(n) for n in numbers[:8])
    return shown + (f" and {len(numbers) - 8} more" if len(numbers) > 8 else "")


def equal_parts_problems(
    outline_m: np.ndarray,
    lines_m: np.ndarray,
    parts: int,
    tolerance: float,
    hole_m: np.ndarray | None = None,
    reach_m: float | None = None,
) -> tuple[list[str], tuple[PieceEffect, ...]]:
    """Appendix F's success by this verifier: the problems of cut lines (K, 2, 2) drawn across an
    outline (the eval's true one) against `parts` pieces equal in area within `tolerance`, and
    the pieces (at keymps.outcome.pieces.RESOLUTION_M, shares of the pieces' own sum). Each line
    is lengthened by `reach_m` at both ends: keymps.outcome.pieces.REACH_M for planned lines (the
    paper's design), PARTING_M for a knife's cuts, as the outcome stage parts pieces."""
    from keymps.outcome.pieces import CRUMB_FRACTION, REACH_M, RESOLUTION_M, Regions

    lines = np.asarray(lines_m, float).reshape(-1, 2, 2)
    reach = REACH_M if reach_m is None else reach_m
    regions = Regions(outline_m, lines, hole_m, RESOLUTION_M, reach)
    total = float(regions.areas_m2.sum())
    pieces = tuple(
        PieceEffect(1, float(area), float(area) / total, np.zeros((0, 2)))
        for area in sorted(regions.areas_m2, reverse=True)
        if area >= CRUMB_FRACTION * total
    )
    cuts = tuple(CutEffect(k, 1, float(np.linalg.norm(b - a)), 0.0, np.array([[a, b]]))
                 for k, (a, b) in enumerate(lines))  # fmt: skip
    intent = PlanIntent(pieces=parts, equal=tolerance, equal_by="area")
    food = Food(1, 0.0, np.asarray(outline_m, float))
    return intent_problems(Effect(cuts=cuts, pieces=pieces), intent, food), pieces
