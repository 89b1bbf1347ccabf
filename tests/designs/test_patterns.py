"""Exact parametric designs: each checked against its defining geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from keymps.designs import patterns
from keymps.designs.outline import rectangle_polygon
from keymps.designs.patterns import Outline


def disk(radius=50.0, centre=(100.0, 80.0)) -> Outline:
    polygon = patterns.circle_polygon(centre, radius, 2000)
    return Outline("round", polygon, np.array(centre), 0.0)


def bar(length=200.0, width=40.0, angle=0.0, centre=(150.0, 100.0)) -> Outline:
    polygon = rectangle_polygon(centre, length, width, angle)
    kind = "square" if length == width else "elongated"
    return Outline(kind, polygon, np.array(centre), angle)


def test_offsets_by_count_and_width():
    assert np.allclose(patterns.offsets_by_count(90, 3), [30, 60])
    assert np.allclose(patterns.offsets_by_width(100, 25), [25, 50, 75])  # no cut at the far end
    assert np.allclose(patterns.offsets_by_width(100, 30), [30, 60, 90])
    assert np.allclose(patterns.offsets_by_width(160, 20, count=4), [20, 40, 60, 80])
    with pytest.raises(ValueError):
        patterns.offsets_by_width(100, 0)


def test_parallel_slices_span_the_object():
    outline = bar()
    cuts = patterns.parallel_slices(outline, 0.0, parts=4, overshoot=2.0)
    assert np.allclose(cuts[:, 0, 0], [100, 150, 200])
    assert np.allclose(cuts[:, :, 1], [[78, 122]] * 3)  # 40 wide plus 2 each side


def test_rotated_bar_cuts_are_perpendicular_to_its_axis():
    angle = math.radians(30)
    outline = bar(angle=angle)
    cuts = patterns.parallel_slices(outline, angle, width=50.0)
    assert len(cuts) == 3
    for start, end in cuts:
        assert abs(np.dot(end - start, patterns.direction(angle))) < 1e-9
        assert np.linalg.norm(end - start) == pytest.approx(40.0)


def test_both_tips():
    cuts = patterns.both_tips(bar(), 0.0, inset=15.0)
    assert np.allclose(cuts[:, 0, 0], [65.0, 235.0])


@pytest.mark.parametrize("parts", [2, 3, 5, 6, 8, 10])
def test_radial_slices_have_equal_angles(parts):
    outline = disk()
    cuts = patterns.radial_slices(outline, parts)
    rays = []
    for start, end in cuts:
        for point in (start, end):
            offset = point - outline.centre
            if np.linalg.norm(offset) > 1:
                rays.append(math.degrees(math.atan2(offset[1], offset[0])) % 360)
                assert np.linalg.norm(offset) == pytest.approx(50.0, abs=0.01)
    gaps = np.diff(sorted(rays) + [sorted(rays)[0] + 360])
    assert len(rays) == parts and np.allclose(gaps, 360 / parts)


def test_grid_shape_prefers_square_cells():
    assert patterns.grid_shape(6) == (2, 3)
    assert patterns.grid_shape(4) == (2, 2)
    assert patterns.grid_shape(10) == (2, 5)
    assert patterns.grid_shape(7) == (1, 7)
    assert patterns.grid_shape(3, aspect=3.0) == (1, 3)


def test_grid_cuts_and_cell_centres():
    outline = bar(120, 120)
    cuts = patterns.grid_cuts(outline, 2, 3)
    assert len(cuts) == 2 + 1
    centres = patterns.grid_cell_centres(outline, 2, 3)
    assert np.allclose(sorted(set(np.round(centres[:, 0], 6))), [110, 150, 190])
    assert np.allclose(sorted(set(np.round(centres[:, 1], 6))), [70, 130])


def test_ring_of_dots():
    dots = patterns.ring_of_dots((0, 0), 10.0, 15)
    assert dots.shape == (15, 2, 2) and np.array_equal(dots[:, 0], dots[:, 1])
    assert np.allclose(np.linalg.norm(dots[:, 0], axis=1), 10.0)
    assert np.allclose(dots[0, 0], [0, -10])  # starts at the top
    gaps = np.linalg.norm(np.diff(dots[:, 0], axis=0), axis=1)
    assert np.allclose(gaps, gaps[0])


def test_dots_along_an_inset_square_are_evenly_spaced():
    path = patterns.inset_path(bar(100, 100), 10.0)
    points = patterns.points_along_closed_path(path, 8)
    closed = np.vstack([points, points[:1]])
    # the raster places the inset to a cell (1/600 of the outline: 0.17 mm here; an edge on a
    # cell's centre is the worst case)
    assert np.abs(np.abs(points - [150, 100]).max(axis=1) - 40.0).max() < 1.01 * 100 / 600
    assert np.abs(np.abs(np.diff(closed, axis=0)).sum(axis=1) - 40.0).max() < 1.01 * 200 / 600


def rounded_rectangle(length: float, width: float, corner: float, angle: float) -> np.ndarray:
    """A rounded rectangle's outline (a square cake), turned by `angle`, centred on (150, 100)."""
    half = np.array([length / 2 - corner, width / 2 - corner])
    arcs = []
    for k, (sx, sy) in enumerate([(1, 1), (-1, 1), (-1, -1), (1, -1)]):
        turn = np.linspace(k * math.pi / 2, (k + 1) * math.pi / 2, 24)
        arcs.append(half * [sx, sy] + corner * np.stack([np.cos(turn), np.sin(turn)], axis=1))
    ring = np.concatenate(arcs)
    c, s = math.cos(angle), math.sin(angle)
    return ring @ np.array([[c, s], [-s, c]]) + [150.0, 100.0]


def distance_to_boundary(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    a, b = polygon, np.roll(polygon, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum("pij,ij->pi", points[:, None] - a, ab) / (ab**2).sum(axis=1), 0, 1)
    nearest = a + t[..., None] * ab
    return np.linalg.norm(nearest - points[:, None], axis=2).min(axis=1)


def test_an_inset_follows_the_measured_outline_at_its_distance():
    """The ring of dots on a square cake ran along a rectangle inside its outline: at the
    rounded corners and along a wavy side it came nearer the edge than asked. Every point of
    the path (where the dots go) now lies the inset from the outline, to two raster cells,
    over 200 outlines."""
    rng = np.random.default_rng(5)
    for _ in range(200):
        length = rng.uniform(80, 160)
        width = length * rng.uniform(0.5, 1.0)
        polygon = rounded_rectangle(length, width, rng.uniform(0, 0.2) * width,
                                    rng.uniform(-math.pi, math.pi))  # fmt: skip
        polygon += rng.normal(0, 0.15, polygon.shape)  # a measured outline is not smooth
        inset = rng.uniform(5, 0.4 * width)
        outline = Outline("square", polygon, polygon.mean(axis=0), 0.0)
        path = patterns.inset_path(outline, inset)
        dense = np.concatenate([np.linspace(a, b, 8, endpoint=False)
                                for a, b in zip(path, np.roll(path, -1, axis=0), strict=True)])  # fmt: skip
        cell = np.ptp(polygon, axis=0).max() / 600
        assert np.abs(distance_to_boundary(dense, polygon) - inset).max() < 2.2 * cell
    with pytest.raises(ValueError, match="inset larger than the object"):
        patterns.inset_path(bar(100, 40), 20.5)


def test_points_equally_apart_keep_dots_apart_at_corners():
    """10 dots on a 30 mm square spaced by arc: the two either side of a corner came 8.5 mm
    apart, a dot's diameter (8 mm) from merging; equally apart they are all 10.8 mm apart. On
    120 turned rounded rectangles the closest two are never closer than by arc, and from 6
    points on (a ring the layout lays out) every gap is the same."""
    square = rectangle_polygon((0, 0), 30.0, 30.0)
    by_arc = patterns.gaps(patterns.points_along_closed_path(square, 10))
    apart = patterns.gaps(patterns.points_equally_apart(square, 10))
    assert np.ptp(apart) < 1e-3 and apart.min() > 10.7 > 8.5 > by_arc.min()
    rng = np.random.default_rng(11)
    for _ in range(120):
        length = rng.uniform(20, 120)
        width = length * rng.uniform(0.4, 1.0)
        path = rounded_rectangle(length, width, rng.uniform(0, 0.3) * width, rng.uniform(-3, 3))
        count = int(rng.integers(3, 30))
        gaps = patterns.gaps(patterns.points_equally_apart(path, count))
        assert (
            gaps.min() >= patterns.gaps(patterns.points_along_closed_path(path, count)).min() - 1e-9
        )
        assert count < 6 or np.ptp(gaps) < 1e-3 * gaps.mean()
    circle = patterns.circle_polygon((0, 0), 40.0, 360)
    ring = patterns.points_equally_apart(circle, 12)
    assert np.abs(np.linalg.norm(ring, axis=1) - 40.0).max() < 0.01
    assert np.allclose(ring[0], [0, -40], atol=0.01)  # starts at the top, like the arc spacing


def test_concentric_rings_and_spiral_are_chains():
    rings = patterns.concentric_rings((0, 0), [30, 20], segments=24)
    assert rings.shape == (48, 2, 2)
    for ring, radius in zip(np.split(rings, 2), (30, 20), strict=True):
        assert np.allclose(ring[1:, 0], ring[:-1, 1]) and np.allclose(ring[-1, 1], ring[0, 0])
        assert np.allclose(np.linalg.norm(ring.reshape(-1, 2), axis=1), radius)
    swirl = patterns.spiral((0, 0), 2.0, 40.0, turns=3, segments=90)
    assert np.allclose(swirl[1:, 0], swirl[:-1, 1])
    radii = np.linalg.norm(swirl[:, 1], axis=1)
    assert np.all(np.diff(radii) > 0) and radii[-1] == pytest.approx(40.0)
    turns = np.unwrap(np.arctan2(swirl[:, 1, 1], swirl[:, 1, 0]))
    assert (turns[-1] - np.arctan2(swirl[0, 0, 1], swirl[0, 0, 0])) == pytest.approx(6 * math.pi)


def test_stars():
    pentagram = patterns.star((0, 0), 10.0, 5)
    assert pentagram.shape == (5, 2, 2)
    lengths = np.linalg.norm(pentagram[:, 1] - pentagram[:, 0], axis=1)
    assert np.allclose(lengths, 2 * 10 * math.sin(2 * math.pi / 5))  # chords skipping one tip
    outline = patterns.star((0, 0), 10.0, 4)
    assert outline.shape == (8, 2, 2) and np.allclose(outline[1:, 0], outline[:-1, 1])
    six = patterns.star((0, 0), 10.0, 6, inner_ratio=0.5)
    radii = np.linalg.norm(six[:, 0], axis=1)
    assert np.allclose(radii[0::2], 10.0) and np.allclose(radii[1::2], 5.0)


@pytest.mark.parametrize(("text", "segments"), [("8", 7), ("1", 2), ("27", 8), ("2026", 22)])
def test_seven_segment_counts(text, segments):
    pairs = patterns.seven_segment(text, (0, 0), 20.0)
    assert len(pairs) == segments
    width, height = patterns.seven_segment_size(text, 20.0)
    points = pairs.reshape(-1, 2)
    assert np.all(points >= [-width / 2 - 1e-9, -height / 2 - 1e-9])
    assert np.allclose(points.max(axis=0), [width / 2, height / 2])
    assert np.isclose(points[:, 1].min(), -height / 2)


def test_seven_segment_rejects_letters():
    with pytest.raises(ValueError, match="no seven-segment form for 'x'"):
        patterns.seven_segment("1x", (0, 0), 10)


def test_dot_per_radial_slice_sits_at_each_wedge_centroid():
    outline = disk(radius=60.0)
    dots = patterns.dot_per_radial_slice(outline, 6)
    distance = np.linalg.norm(dots[:, 0] - outline.centre, axis=1)
    assert np.allclose(distance, 2 * 60 * math.sin(math.pi / 6) / (3 * math.pi / 6))
    angles = np.round(np.degrees(np.arctan2(*(dots[:, 0] - outline.centre).T[::-1])), 6) % 360
    assert np.allclose(sorted(angles), [0, 60, 120, 180, 240, 300])  # between the cuts


def test_chord_misses_outside_the_object():
    assert patterns.chord(disk(), np.array([0.0, 0.0]), 0.0) is None


@pytest.mark.parametrize(
    ("slicing_deg", "start_to_end"),
    [
        (0, (0, 1)),
        (90, (1, 0)),
        (180, (0, 1)),
        (-90, (1, 0)),
        (10, (0, 1)),
        (80, (1, 0)),
    ],
)
def test_cuts_run_left_to_right_or_top_to_bottom(slicing_deg, start_to_end):
    cuts = patterns.parallel_slices(bar(100, 100), math.radians(slicing_deg), parts=3)
    for start, end in cuts:
        d = (end - start) / np.linalg.norm(end - start)
        assert np.dot(d, start_to_end) > 0.9


def test_radial_cuts_start_at_the_top_and_turn_counter_clockwise_on_screen():
    outline = disk(radius=50.0, centre=(0.0, 0.0))
    first, second = patterns.radial_slices(outline, 4)
    assert np.allclose(first, [[0, -50], [0, 50]], atol=0.01)  # top to bottom
    assert np.allclose(second, [[-50, 0], [50, 0]], atol=0.01)  # then left to right
    rays = patterns.radial_slices(outline, 3)
    assert np.allclose(rays[0], [[0, -50], [0, 0]], atol=0.01)  # the first ray is the top one
    assert rays[1, 0, 0] < 0  # the next one to the left of it (counter-clockwise on screen)
    # rays run from the edge in to the centre: a knife's trailing edge ends along the ray
    assert np.allclose(rays[:, 1], 0.0, atol=1e-9)
