"""Turn a read instruction (Intent) and a measured object (CropShape) into exact keypoint pairs."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from keymps.designs import patterns
from keymps.designs.crop_shape import CropShape
from keymps.designs.grammar import Intent
from keymps.designs.outline import inset_polygon
from keymps.designs.patterns import Outline
from keymps.errors import KeympsError

DOT_SPACING_MM = 25.0
"""Spacing of dots around an object when the sentence gives no count."""
RING_FRACTION = 0.78
"""Radius of a ring of dots as a fraction of a round object's radius (space from the edge)."""
TIP_FRACTION = 0.1
"""Both tips: each cut is this fraction of the length in from its end (5-30 mm)."""
CAP_MARGIN_MM = 2.0
"""Both tips of a capped body (an eggplant): the cut on the cap's side is this far into the body,
so that the cap comes off whole."""


OVERSHOOT_MM = 1.0
"""How far a cut reaches past the object's edge (then clipped to its bounding box)."""


def _overshoot(outline: Outline) -> float:
    return OVERSHOOT_MM


AMBIGUOUS_TURN_DEG = 5.0
"""An object whose sides are within this of 45 degrees from the image's has no side nearer the
image's vertical than the other: "vertically" is refused on it."""


def _slicing_angle(intent: Intent, shape: CropShape) -> float:
    """The direction along which slices follow each other (cuts are perpendicular to it).

    Directions are the object's own: "vertical" cuts run along the object's axis nearest the
    image's vertical, "lengthwise" along its long axis. A round object's axes are the image's;
    it has no length. Strips of a long object are cut along its length."""
    o = shape.outline
    orientation = intent.orientation
    if orientation is None and intent.piece_shape == "strip" and o.kind == "elongated":
        orientation = "lengthwise"
    if orientation in ("vertical", "horizontal"):
        return _nearest_axis(shape, 0.0 if orientation == "vertical" else math.pi / 2)
    if o.kind == "round" and orientation is not None:
        raise KeympsError(
            f"a round object has no length to cut {orientation} ({shape.describe()}): "
            "ask for vertical or horizontal cuts, or N equal wedges"
        )
    if orientation == "lengthwise":
        return o.axis_angle + math.pi / 2
    return o.axis_angle


def _nearest_axis(shape: CropShape, image_angle: float) -> float:
    """The object's axis nearest `image_angle` (radians from the image's +x towards +y)."""
    o = shape.outline
    axis = 0.0 if o.kind == "round" else o.axis_angle
    turn = math.remainder(axis - image_angle, math.pi / 2)
    if abs(abs(math.degrees(turn)) - 45.0) < AMBIGUOUS_TURN_DEG:
        raise KeympsError(
            f"the {shape.describe()} is turned {abs(math.degrees(turn)):.0f} degrees from the "
            "image's axes: none of its sides is nearer the image's vertical than the other, so "
            "'vertical' and 'horizontal' say no direction; ask for lengthwise or crosswise cuts"
        )
    return image_angle + turn


def turn_note(shape: CropShape, slicing_angle: float) -> str:
    """', along the object's own axes (turned N degrees from the image's)' when they are."""
    o = shape.outline
    if o.kind == "round":
        return ""
    turn = math.degrees(math.remainder(slicing_angle, math.pi / 2))
    if abs(turn) < 0.05:
        return ""
    return f", along the object's own axes (turned {abs(turn):.0f} degrees from the image's)"


def _segments(budget: int, wanted: int, minimum: int = 8) -> int:
    return max(min(wanted, budget), min(minimum, budget))


def design(intent: Intent, shape: CropShape, max_pairs: int) -> tuple[np.ndarray, str]:
    """(pairs in millimetres of the crop frame, a one-sentence rationale)."""
    if intent.family == "cut":
        _check_piece_shape(intent, shape)
        return _cuts(intent, shape)
    return _icing(intent, shape, max_pairs)


def _cuts(intent: Intent, shape: CropShape) -> tuple[np.ndarray, str]:
    o = shape.outline
    over = _overshoot(o)
    what = shape.describe()
    if intent.design == "equal":
        assert intent.count is not None
        if o.kind == "round":
            return patterns.radial_slices(o, intent.count, overshoot=over), (
                f"{what}: {intent.count} equal wedges, "
                + ("cuts through the centre" if intent.count % 2 == 0 else "rays from the centre")
                + f" at {360 / intent.count:g} degree steps"
            )
        if o.kind == "square":
            rows, cols = patterns.grid_shape(intent.count, o.length / o.width)
            return patterns.grid_cuts(o, rows, cols, over), (
                f"{what}: {intent.count} equal pieces as a {rows} x {cols} grid"
            )
        return patterns.parallel_slices(o, o.axis_angle, parts=intent.count, overshoot=over), (
            f"{what}: {intent.count} equal slices across its length"
        )
    if intent.design == "width":
        return _width_slices(intent, shape, over)
    angle = _slicing_angle(intent, shape)
    along = turn_note(shape, angle) if intent.orientation in ("vertical", "horizontal") else ""
    if intent.design == "parallel":
        assert intent.count is not None
        cuts = f"{intent.orientation} cuts" if intent.orientation else "parallel cuts"
        return patterns.parallel_slices(o, angle, parts=intent.count, overshoot=over), (
            f"{what}: {intent.count} equal parts with {intent.count - 1} {cuts}{along}"
        )
    low, high = o.extent(angle)
    if intent.design == "middle":
        return patterns.parallel_cuts(o, angle, [(high - low) / 2], over), (
            f"{what}: one {intent.orientation + ' ' if intent.orientation else ''}cut through "
            f"the middle{along}"
        )
    if intent.design == "tips":
        return _tips(intent, shape, angle, over)
    raise KeympsError(f"the offline planner has no design for {intent.describe()}")


def _tips(intent: Intent, shape: CropShape, angle: float, over: float) -> tuple[np.ndarray, str]:
    """Both tips off: `inset` in from each end of the body, or at the base of a cap (an end of
    another colour the body was measured without)."""
    o = shape.outline
    low, high = o.extent(angle)
    inset = min(max(TIP_FRACTION * (high - low), 5.0), 30.0)
    if intent.slice_width_mm is not None:
        inset = _scaled_width(intent, intent.slice_width_mm, high - low)
    insets = [inset, inset]
    along = math.cos(angle - o.axis_angle)
    capped = shape.trimmed_mm if along > 0.99 else shape.trimmed_mm[::-1] if along < -0.99 else ()
    notes = []
    for end, trimmed in enumerate(capped):
        if trimmed > 0:
            insets[end] = CAP_MARGIN_MM
            notes.append(f"the {trimmed / 10:.1f} cm cap cut off at its base")
    if sum(insets) >= high - low:
        raise KeympsError(
            f"{inset:g} mm off each end leaves nothing of the {shape.describe()} "
            f"({(high - low) / 10:.1f} cm long)"
        )
    plain = f"{inset / 10:.1f} cm from " + ("each end" if not notes else "the other end")
    return patterns.parallel_cuts(o, angle, [insets[0], high - low - insets[1]], over), (
        f"{shape.describe()}: both tips cut off, " + ", ".join([*notes, plain])
    )


def _scaled_width(intent: Intent, width: float, measured: float) -> float:
    """A width of the sentence in the picture's millimetres: the sentence's stated length of the
    object is the scale ("10 cm long, 5 cm slices" means two halves)."""
    if intent.object_length_mm:
        return width * measured / intent.object_length_mm
    return width


def _check_piece_shape(intent: Intent, shape: CropShape) -> None:
    """Refuse pieces of a shape this object cannot give ("9 squares" of a round cake)."""
    o, asked = shape.outline, intent.piece_shape
    count = intent.count or ""
    if asked in ("wedge", "square") and intent.design != "equal":
        raise KeympsError(
            f"{asked}s come from equal parts, not from {intent.describe()}: ask for "
            f"{count or 'N'} equal {asked}s"
        )
    if asked == "wedge" and o.kind != "round":
        raise KeympsError(
            f"{count} equal wedges need a round object; this is a {shape.describe()}: "
            f"ask for {count} equal pieces (a grid or parallel slices)"
        )
    if asked == "strip" and o.kind == "round":
        raise KeympsError(
            f"a round object has no strips ({shape.describe()}): its equal parts are wedges; "
            f"ask for {count or 'N'} equal wedges, or plan with a VLM"
        )
    if asked == "round" and (o.kind != "elongated" or intent.orientation == "lengthwise"):
        raise KeympsError(
            f"rounds are slices across a long object, and this is a {shape.describe()}"
            + (" cut lengthwise" if o.kind == "elongated" else "")
            + ": ask for slices"
        )
    if asked == "square":
        if o.kind == "round":
            raise KeympsError(
                f"a round object cannot be cut into {count} equal squares ("
                f"{shape.describe()}): ask for {count} equal wedges, or plan with a VLM"
            )
        rows, cols = patterns.grid_shape(intent.count or 1, o.length / o.width)
        cell = (o.length / cols) / (o.width / rows)
        if not 0.8 <= cell <= 1.25:
            raise KeympsError(
                f"{count} equal pieces of the {shape.describe()} are a {rows} x {cols} "
                f"grid of {o.length / cols / 10:.1f} x {o.width / rows / 10:.1f} cm rectangles, "
                "not squares: ask for equal pieces, or another count"
            )


def _width_slices(intent: Intent, shape: CropShape, over: float) -> tuple[np.ndarray, str]:
    o = shape.outline
    assert intent.slice_width_mm is not None
    angle = _slicing_angle(intent, shape)
    low, high = o.extent(angle)
    measured = high - low
    width = _scaled_width(intent, intent.slice_width_mm, measured)
    note = ""
    if intent.object_length_mm and abs(measured / intent.object_length_mm - 1) > 0.15:
        note = (
            f"; the picture measures {measured / 10:.1f} cm, the sentence says "
            f"{intent.object_length_mm / 10:g} cm: slices follow the sentence's proportions"
        )
    if intent.count is None and measured / width > 1000:
        raise KeympsError(
            f"slices {intent.slice_width_mm / 10:g} cm wide would need more than 1000 cuts"
        )
    offsets = patterns.offsets_by_width(measured, width, intent.count, tolerance=0.02 * width)
    if intent.count is None:
        # as many as fit, the end piece at least half a slice (the eval's ground truth rule)
        offsets = offsets[offsets <= measured - width / 2 + 1e-9]
    if len(offsets) == 0:
        raise KeympsError(
            f"slices {intent.slice_width_mm / 10:g} cm wide do not fit the object "
            f"({measured / 10:.1f} cm along the cut direction)"
        )
    if intent.count is not None and len(offsets) < intent.count:
        raise KeympsError(
            f"only {len(offsets)} of the {intent.count} slices {intent.slice_width_mm / 10:g} cm "
            f"wide fit the object ({measured / 10:.1f} cm along the cut direction): ask for fewer "
            "or thinner slices"
        )
    pairs = patterns.parallel_cuts(o, angle, offsets, over)
    along = turn_note(shape, angle) if intent.orientation in ("vertical", "horizontal") else ""
    return pairs, (
        f"{shape.describe()}: {len(offsets)} cuts {intent.slice_width_mm / 10:g} cm apart from "
        f"one end{along}{note}"
    )


def _ring_count(perimeter: float, given: int | None) -> int:
    if given is not None:
        return given
    return int(min(max(round(perimeter / DOT_SPACING_MM), 6), 24))


Layout = tuple[np.ndarray, str]
"""Pairs (K, 2, 2) in crop millimetres and one line saying how they were laid out."""


def _icing(intent: Intent, shape: CropShape, max_pairs: int) -> Layout:
    """The icing design `intent` names, laid out on `shape` in at most `max_pairs` pairs."""
    if intent.design == "dots_ring" and (intent.layers or 1) > 1:
        return _rings_of_dots(intent, shape, max_pairs)
    lay_out = _ICING.get(intent.design)
    if lay_out is None:
        raise KeympsError(f"the offline planner has no design for {intent.describe()}")
    return lay_out(intent, shape, max_pairs)


def _inner(o: Outline) -> float:
    """The radius of the largest circle about the centre inside the outline, mm."""
    return o.inner_radius() if o.kind != "round" else o.radius


def _dot(intent: Intent, shape: CropShape, max_pairs: int) -> Layout:
    return patterns.dots(
        np.array([shape.outline.centre])
    ), f"{shape.describe()}: one dot in the middle"


def _dots_ring(intent: Intent, shape: CropShape, max_pairs: int) -> Layout:
    fraction = _ring_fraction(intent, shape, RING_FRACTION)
    path, ring_note = _dot_path(shape.outline, fraction, _follows_edge(intent))
    count = _ring_count(patterns.perimeter(path), intent.count)
    return _ring_dots(shape.outline, path, count), (
        f"{shape.describe()}: {count} dots evenly spaced {ring_note}"
    )


def _rings(intent: Intent, shape: CropShape, max_pairs: int) -> Layout:
    """Concentric icing rings on a round object, nested outlines on any other."""
    o, what = shape.outline, shape.describe()
    layers = intent.count or 1
    if layers * 4 > max_pairs:
        raise KeympsError(
            f"{layers} icing rings need at least {layers * 4} pairs, more than "
            f"planner.max_pairs = {max_pairs}"
        )
    if o.kind == "round" and not _follows_edge(intent):
        outer = _ring_fraction(intent, shape, RING_FRACTION) * o.radius
        radii = [outer - k * 0.7 * outer / layers for k in range(layers)]
        segments = _segments(max_pairs // layers, 36)
        return patterns.concentric_rings(o.centre, radii, segments), (
            f"{what}: {layers} concentric icing rings, radii "
            + ", ".join(f"{r / 10:.1f}" for r in radii)
            + " cm"
        )
    small = min(o.length, o.width)
    first = (1 - _ring_fraction(intent, shape, 0.76)) * small / 2
    if intent.edge_distance_mm is not None:
        first = intent.edge_distance_mm  # on a round object too, not scaled by its radius
    insets = [first + k * 0.7 * (small / 2 - first) / layers for k in range(layers)]
    paths = _fitting(max_pairs, [_edge_path(o, inset) for inset in insets])
    loops = [patterns.polyline(path, closed=True) for path in paths]
    return np.concatenate(loops, axis=0), (
        f"{what}: {layers} nested icing outlines following the edge"
    )


LOOP_TOLERANCES_MM = (0.5, 1.0, 2.0)
"""How far nested icing outlines may cut inside the measured ones, tried in turn, to fit
planner.max_pairs (the edge distance is held to 1.5 mm at least)."""


def _fitting(max_pairs: int, paths: list[np.ndarray]) -> list[np.ndarray]:
    """Closed paths as they are, or thinned (LOOP_TOLERANCES_MM) until their segments fit
    `max_pairs` pairs."""
    fitting = paths
    for tolerance in LOOP_TOLERANCES_MM:
        if sum(len(path) for path in fitting) <= max_pairs:
            break
        fitting = [patterns.thinned_path(path, tolerance) for path in paths]
    return fitting


def _dots_spiral(intent: Intent, shape: CropShape, max_pairs: int) -> Layout:
    o = shape.outline
    fraction = _ring_fraction(intent, shape, 0.85)
    path, ring_note = _dot_path(o, fraction, _follows_edge(intent))
    count = _ring_count(patterns.perimeter(path), intent.count)
    dots = _ring_dots(o, path, count)
    segments = _segments(max_pairs - count, 48)
    swirl = patterns.spiral(o.centre, 0.06 * _inner(o), 0.6 * _inner(o), 2.5, segments)
    return np.concatenate([dots, swirl], axis=0), (
        f"{shape.describe()}: {count} dots {ring_note} and a 2.5-turn spiral inside"
    )


def _spiral(intent: Intent, shape: CropShape, max_pairs: int) -> Layout:
    o = shape.outline
    segments = _segments(max_pairs, 60)
    return patterns.spiral(o.centre, 0.05 * _inner(o), 0.8 * _inner(o), 3.0, segments), (
        f"{shape.describe()}: a 3-turn spiral from the centre"
    )


def _star(intent: Intent, shape: CropShape, max_pairs: int) -> Layout:
    inner, points = _inner(shape.outline), intent.count or 5
    return patterns.star(shape.outline.centre, 0.7 * inner, points), (
        f"{shape.describe()}: a {points}-pointed star in the middle, "
        f"{1.4 * inner / 10:.1f} cm across"
    )


def _digits(intent: Intent, shape: CropShape, max_pairs: int) -> Layout:
    """The text in seven-segment lines, as tall as fits well inside the object."""
    assert intent.text is not None
    o = shape.outline
    text_width, _ = patterns.seven_segment_size(intent.text, 1.0)
    # the text box must fit well inside the object: half-diagonal within 80 % of its inradius
    height = 0.8 * _inner(o) / math.hypot(text_width / 2, 0.5)
    if o.kind == "elongated":
        height = min(0.8 * o.length / text_width, 0.7 * o.width)
    return patterns.seven_segment(intent.text, o.centre, height), (
        f"{shape.describe()}: {intent.text!r} in seven-segment icing lines, "
        f"{height / 10:.1f} cm tall"
    )


def _dot_per_slice(intent: Intent, shape: CropShape, max_pairs: int) -> Layout:
    """A dot in each of `count` wedges (round) or grid pieces (any other shape)."""
    assert intent.count is not None
    o, what = shape.outline, shape.describe()
    if o.kind == "round":
        return patterns.dot_per_radial_slice(o, intent.count), (
            f"{what}: one dot at the middle of each of {intent.count} equal wedges"
        )
    rows, cols = patterns.grid_shape(intent.count, o.length / o.width)
    return patterns.dot_per_grid_cell(o, rows, cols), (
        f"{what}: one dot at the middle of each piece of a {rows} x {cols} grid"
    )


def _free(intent: Intent, shape: CropShape, max_pairs: int) -> Layout:
    o = shape.outline
    fraction = _ring_fraction(intent, shape, 0.85)
    path, ring_note = _dot_path(o, fraction, _follows_edge(intent))
    count = _ring_count(patterns.perimeter(path), None)
    star = patterns.star(o.centre, 0.5 * _inner(o), 5)
    return np.concatenate([_ring_dots(o, path, count), star], axis=0), (
        f"{shape.describe()}: a free design: {count} dots {ring_note} and a five-pointed star "
        "in the middle"
    )


def _rings_of_dots(intent: Intent, shape: CropShape, max_pairs: int) -> tuple[np.ndarray, str]:
    """Concentric rings of dots, the outer one where a single ring would be, spaced inwards."""
    o = shape.outline
    layers = intent.layers or 1
    outer = _ring_fraction(intent, shape, RING_FRACTION)
    fractions = [outer - k * 0.7 * outer / layers for k in range(layers)]
    rings, counts = [], []
    for fraction in fractions:
        path, _ = _dot_path(o, fraction, _follows_edge(intent))
        count = _ring_count(patterns.perimeter(path), intent.count)
        if intent.count is None:
            count = max(3, int(round(patterns.perimeter(path) / DOT_SPACING_MM)))
        rings.append(_ring_dots(o, path, count))
        counts.append(count)
    pairs = np.concatenate(rings, axis=0)
    if len(pairs) > max_pairs:
        raise KeympsError(
            f"{layers} rings of dots need {len(pairs)} pairs, more than planner.max_pairs = "
            f"{max_pairs}"
        )
    return pairs, (
        f"{shape.describe()}: {layers} concentric rings of dots ("
        + ", ".join(str(n) for n in counts)
        + " dots, outer to inner)"
    )


def _ring_fraction(intent: Intent, shape: CropShape, default: float) -> float:
    """Where the (outer) ring runs, as a fraction of the way from the centre to the edge: the
    sentence's distance from the edge, else the design's own spacing."""
    edge = intent.edge_distance_mm
    if edge is None:
        return default
    o = shape.outline
    half = o.radius if o.kind == "round" else min(o.length, o.width) / 2
    if edge > 0.8 * half:
        raise KeympsError(
            f"{edge / 10:g} cm from the edge leaves no room for a ring on the {shape.describe()}"
            f": at most {0.8 * half / 10:.1f} cm"
        )
    return 1 - edge / half


def _follows_edge(intent: Intent) -> bool:
    """The sentence gives a distance from the edge: rings follow the measured outline."""
    return intent.edge_distance_mm is not None


def _dot_path(o: Outline, fraction: float, follow_edge: bool = False) -> tuple[np.ndarray, str]:
    """The ring `fraction` of the way from the centre to the edge: a circle on a round object,
    unless `follow_edge` (the sentence gave a distance from the edge): then, as on any other
    object, the measured outline moved in, so a wavy crust keeps the distance all round."""
    if o.kind == "round" and not follow_edge:
        radius = fraction * o.radius
        return patterns.circle_polygon(o.centre, radius, 360), (
            f"on a circle {2 * radius / 10:.1f} cm across, {(o.radius - radius) / 10:.1f} cm "
            "in from the edge"
        )
    inset = (1 - fraction) * (o.radius if o.kind == "round" else min(o.length, o.width) / 2)
    return _edge_path(o, inset), f"along the edge, {inset / 10:.1f} cm in from it"


def _edge_path(o: Outline, inset: float) -> np.ndarray:
    """The measured outline moved `inset` mm in: a round object's too (patterns.inset_path
    gives it a circle), for a wavy crust holds the distance only along its own outline."""
    if o.kind == "round" and inset > 0:
        return inset_polygon(o.polygon, inset)
    return patterns.inset_path(o, inset)


def _ring_dots(o: Outline, path: np.ndarray, count: int) -> np.ndarray:
    """`count` dots along a ring: evenly by arc on a circle, each as far from the next on any
    other path (spaced by arc, the two either side of a corner would merge first)."""
    if o.kind == "round":
        return patterns.dots_along_path(path, count)
    return patterns.dots(patterns.points_equally_apart(path, count))


_ICING: dict[str, Callable[[Intent, CropShape, int], Layout]] = {
    "dot": _dot,
    "dots_ring": _dots_ring,
    "rings": _rings,
    "dots_spiral": _dots_spiral,
    "spiral": _spiral,
    "star": _star,
    "digits": _digits,
    "dot_per_slice": _dot_per_slice,
    "free": _free,
}
"""How each icing design is laid out (dots_ring in several layers: _rings_of_dots)."""
