"""The safety check's geometry: pruned and gridded polyline distances, the polygon test and the travel legs' crossing tests against brute force and OpenCV.

Each fast path is held against the implementation it replaced, on generated inputs."""

from __future__ import annotations

import math

import numpy as np

RNG_SEED = 20261201


def test_pruned_polyline_distance_is_exact() -> None:
    from keymps.robot.safety_geometry import _brute_force, distance_to_polyline

    rng = np.random.default_rng(RNG_SEED + 5)
    for trial in range(12):
        polyline = np.cumsum(rng.normal(0, 0.01, (int(rng.integers(40, 400)), 3)), axis=0)
        if trial % 3 == 0:  # sawing: strokes running back over each other
            polyline = np.concatenate([polyline, polyline[::-1], polyline])
        noise = float(rng.choice([0.0, 1e-9, 1e-3, 0.05]))
        picked = polyline[rng.integers(0, len(polyline), 1500)]
        points = picked + rng.normal(0, noise, picked.shape)
        got = distance_to_polyline(points, polyline)
        assert np.abs(got - _brute_force(points, polyline)).max() < 1e-15


def test_grid_pass_of_the_polyline_distance_is_exact_where_it_answers() -> None:
    from keymps.robot.safety_geometry import _brute_force, _near

    rng = np.random.default_rng(RNG_SEED + 11)
    answered = 0
    for trial in range(16):
        steps = rng.normal(
            0, float(rng.choice([1e-4, 1e-3, 1e-2])), (int(rng.integers(20, 500)), 3)
        )
        if trial % 4 == 1:
            steps[:, 0] = 0.0  # a path in a plane (sawing strokes in y-z)
        if trial % 4 == 2:
            steps[rng.random(len(steps)) < 0.2] = 0.0  # repeated points: zero-length segments
        polyline = np.cumsum(steps, axis=0)
        if trial % 4 == 3:  # back and forth over itself
            polyline = np.concatenate([polyline, polyline[::-1] + 1e-6, polyline])
        along = rng.integers(0, len(polyline) - 1, 3000)
        fraction = rng.random((3000, 1))
        points = polyline[along] + fraction * (polyline[along + 1] - polyline[along])
        points += rng.normal(0, float(rng.choice([0.0, 1e-7, 1e-5, 1e-3])), points.shape)
        groups = np.zeros(len(points), np.intp)
        got, near = _near(points, groups, polyline[:-1], polyline[1:], groups[: len(polyline) - 1])
        exact = _brute_force(points, polyline)
        assert np.array_equal(got[near], exact[near])  # the same value to the last bit
        answered += near.sum()
    assert answered > 0.5 * 16 * 3000  # most points near their path are answered by the grid


def test_outside_distance_matches_opencv_on_random_outlines() -> None:
    import cv2

    from keymps.robot.safety_geometry import outside_distance

    rng = np.random.default_rng(RNG_SEED + 6)
    for trial in range(30):
        count = int(rng.integers(3, 900))
        angles = np.sort(rng.uniform(0, 2 * math.pi, count))
        radius = rng.uniform(0.02, 0.08, count) if trial % 2 else 0.05  # concave or convex
        outline = np.column_stack([0.15 + radius * np.cos(angles), 0.09 + radius * np.sin(angles)])
        points = rng.uniform(0.0, 0.3, (2000, 2))
        points[:20] = outline[rng.integers(0, count, 20)]  # on the outline
        contour = outline.astype(np.float32).reshape(-1, 1, 2)
        signed = np.array(
            [cv2.pointPolygonTest(contour, (float(x), float(y)), True) for x, y in points]
        )
        assert np.abs(outside_distance(points, outline) - np.maximum(-signed, 0.0)).max() < 1e-6


def test_outside_distance_with_a_bound_is_brute_forces_to_the_bit() -> None:
    from keymps.robot.safety_geometry import (
        _brute_force,
        _near_bound,
        inside_polygon,
        outside_distance,
    )

    rng = np.random.default_rng(RNG_SEED + 21)
    bounded = 0
    for trial in range(16):
        count = int(rng.integers(100, 1000))  # dense outlines, as detections give
        angles = np.sort(rng.uniform(0, 2 * math.pi, count))
        radius = rng.uniform(0.05, 0.06, (count, 1)) if trial % 2 else 0.07
        centre = np.array([0.15, 0.1])
        outline = centre + radius * np.column_stack([np.cos(angles), np.sin(angles)])
        # work samples a few mm out of the outline (sawing overshoots), in some trials far ones
        scale = rng.uniform(0.98, 1.02, (400, 1))
        near = centre + (outline[rng.integers(0, count, 400)] - centre) * scale
        far = rng.uniform(-0.2, 0.5, (50 if trial % 4 == 3 else 0, 2))
        points = np.concatenate([near, far])
        closed = np.vstack([outline, outline[:1]])
        lifted = np.column_stack([points, np.zeros(len(points))])
        expected = _brute_force(lifted, np.column_stack([closed, np.zeros(len(closed))]))
        inside = inside_polygon(points, outline)
        expected[inside] = 0.0
        assert np.array_equal(outside_distance(points, outline), expected)
        bounded += _near_bound(points[~inside], closed) is not None
    assert bounded >= 6  # the bound's grid pass answered, not only the branch and bound


def test_distance_to_many_polylines_matches_one_polyline_at_a_time() -> None:
    from keymps.robot.safety_geometry import _brute_force, distance_to_polylines

    rng = np.random.default_rng(RNG_SEED + 13)
    for _ in range(8):
        polylines = []
        for _ in range(int(rng.integers(1, 30))):
            size = int(rng.choice([1, 2, 5, 40, 300]))  # a single point, travel, strokes
            steps = rng.normal(0, float(rng.choice([1e-5, 1e-3, 1e-2])), (size, 3))
            polylines.append(rng.uniform(-0.1, 0.1, 3) + np.cumsum(steps, axis=0))
        which = rng.integers(0, len(polylines), 4000)
        anchors = [polylines[i][rng.integers(0, len(polylines[i]))] for i in which]
        points = np.array(anchors) + rng.normal(0, float(rng.choice([1e-7, 1e-4, 3e-2])), (4000, 3))
        expected = np.empty(len(points))
        for index, polyline in enumerate(polylines):
            mine = which == index
            if len(polyline) == 1:
                expected[mine] = np.linalg.norm(points[mine] - polyline[0], axis=1)
            else:
                expected[mine] = _brute_force(points[mine], polyline)
        assert np.array_equal(distance_to_polylines(points, which, polylines), expected)
        # other points (the same in the reverse order) against the grid kept from before
        again = distance_to_polylines(points[::-1].copy(), which[::-1].copy(), polylines)
        assert np.array_equal(again, expected[::-1])


def test_travel_legs_crossing_tests_at_once_match_one_leg_at_a_time() -> None:
    from keymps.motion.compose import TRAVEL_SPACING_M, _crossed_legs
    from keymps.robot.safety_geometry import outside_distance

    def crosses(a: np.ndarray, b: np.ndarray, outline: np.ndarray) -> bool:
        length = float(np.linalg.norm(b - a))
        count = max(2, math.ceil(length / (TRAVEL_SPACING_M / 2)) + 1)
        points = a + np.linspace(0.0, 1.0, count)[:, None] * (b - a)
        return bool((outside_distance(points, outline) <= TRAVEL_SPACING_M).any())

    rng = np.random.default_rng(RNG_SEED + 40)
    answers: list[bool] = []
    for _ in range(40):
        centre, radius = rng.uniform(0.1, 0.3, 2), rng.uniform(0.02, 0.1)
        turns = np.sort(rng.uniform(0, 2 * np.pi, int(rng.integers(3, 40))))
        wobble = radius * rng.uniform(0.6, 1.0, len(turns))[:, None]
        outline = centre + wobble * np.column_stack([np.cos(turns), np.sin(turns)])
        count = int(rng.integers(1, 30))
        starts = list(rng.uniform(0.0, 0.4, (count, 3)))
        ends = list(rng.uniform(0.0, 0.4, (count, 3)))
        ends[0] = starts[0].copy()  # a leg of zero length
        expected = [crosses(a[:2], b[:2], outline) for a, b in zip(starts, ends, strict=True)]
        assert _crossed_legs(starts, ends, outline).tolist() == expected
        answers += expected
    assert 0.1 < sum(answers) / len(answers) < 0.9  # both answers occur often
