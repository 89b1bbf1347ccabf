"""The fast paths against the implementations they replaced, on generated inputs.

Closed-form IK against the iterative solver, batched forward kinematics against Pinocchio,
Ruckig's phases in numpy against `at_time`, the numpy spline against scipy's, the pruned
polyline distance against brute force, the polygon test against OpenCV, and whole runs (IK,
timing, validation) with and without the closed form.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from robot_toolpaths import radial_cuts, ring_of_dots

from keymps.errors import KeympsError
from keymps.robot.model import BUILTIN_TOOLS, RobotModel, Tool, solve_path, tool_poses_down
from keymps.types import ToolPath

RNG_SEED = 20261201


def random_model(rng: np.random.Generator) -> RobotModel:
    kind = str(rng.choice(["ur3", "ur3e"]))
    base = (
        float(rng.uniform(0.14, 0.16)),
        float(rng.uniform(-0.21, -0.19)),
        float(rng.uniform(-0.005, 0.01)),
        float(rng.uniform(85, 95)),
    )
    tcp = (
        float(rng.uniform(-0.004, 0.004)),
        float(rng.uniform(-0.004, 0.004)),
        0.09 + rng.random() * 0.05,
    )
    return RobotModel(kind, base, Tool("t", tcp, "fixed"))


def test_every_analytic_branch_reproduces_the_pose_in_pinocchio() -> None:
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(4):
        model = random_model(rng)
        assert model.closed_form is not None
        qs = rng.uniform(-math.pi, math.pi, (60, 6))
        positions, rotations = model.pinocchio_tool_poses(qs)
        poses = np.zeros((len(qs), 4, 4))
        poses[:, :3, :3], poses[:, :3, 3], poses[:, 3, 3] = rotations, positions, 1.0
        branches = model.closed_form.solve(poses)
        found = 0
        for i, q in enumerate(qs):
            valid = branches[i][~np.isnan(branches[i]).any(axis=1)]
            got_p, got_r = model.pinocchio_tool_poses(valid)
            assert np.abs(got_p - positions[i]).max() < 1e-9
            assert np.abs(got_r - rotations[i]).max() < 1e-9
            wrapped = np.abs((valid - q + math.pi) % (2 * math.pi) - math.pi).max(axis=1)
            found += wrapped.min() < 1e-7  # the configuration we started from is among them
        assert found >= len(qs) - 2  # (a pose next to a singularity may lose its branch)


@pytest.mark.parametrize("make_path", [ring_of_dots, radial_cuts])
def test_closed_form_and_iterative_ik_agree_on_varied_paths(make_path: Any) -> None:
    rng = np.random.default_rng(RNG_SEED + 1)
    solved = 0
    for _ in range(6):
        model = random_model(rng)
        tool_path = make_path(center=(0.15 + rng.uniform(-0.01, 0.01), 0.09))
        closed, closed_error = _solve(model, tool_path)
        model.closed_form, kept = None, model.closed_form
        iterative, iterative_error = _solve(model, tool_path)
        model.closed_form = kept
        assert closed_error == iterative_error  # the same refusal, word for word
        if closed is None or iterative is None:
            continue
        solved += 1
        for a, b in zip(closed.pieces, iterative.pieces, strict=True):
            assert np.abs(a - b).max() < 1e-6
        assert closed.max_position_error_m < 1e-9
    assert solved >= 2


def _solve(model: RobotModel, tool_path: ToolPath) -> tuple[Any, str | None]:
    try:
        return solve_path(model, tool_path), None
    except KeympsError as error:
        return None, str(error)


def test_closed_form_solutions_are_verified_and_continuous() -> None:
    model = RobotModel("ur3", tool=BUILTIN_TOOLS["knife"])
    tool_path = radial_cuts()
    joints = solve_path(model, tool_path)
    points = np.concatenate([piece.points for piece in tool_path.pieces])
    yaws = np.concatenate([piece.yaw for piece in tool_path.pieces])
    seed = model.tool_down_seed(points[0], float(yaws[0]))
    assert model._solve_closed_form(points, yaws, seed) is not None  # no fallback here
    for piece, qs in zip(tool_path.pieces, joints.pieces, strict=True):
        positions, rotations = model.pinocchio_tool_poses(qs)
        targets = tool_poses_down(piece.points, piece.yaw)
        assert np.abs(positions - piece.points).max() < 1e-9
        assert np.abs(rotations - targets[:, :3, :3]).max() < 1e-9
        assert np.abs(np.diff(qs, axis=0)).max() < 0.3  # sparse travel points turn the wrist


def test_a_path_the_closed_form_cannot_take_falls_back_with_the_same_errors() -> None:
    model = RobotModel("ur3", tool=BUILTIN_TOOLS["knife"])
    near = np.array([[0.10, 0.05, 0.08], [0.11, 0.05, 0.08]])
    seed = model.tool_down_seed(near[0], 0.0)
    # A point out of reach has no analytic solution: the iterative solver words the error.
    far = np.vstack([near, [[0.60, 0.40, 0.08]]])
    assert model._solve_closed_form(far, np.zeros(3), seed) is None
    messages = []
    for method in ("auto", "iterative"):
        with pytest.raises(KeympsError, match="inverse kinematics failed at path point 2") as info:
            model.solve_points(far, np.zeros(3), seed, method=method)
        messages.append(str(info.value))
    assert messages[0] == messages[1]
    # Without a closed form (another robot) every point is solved iteratively.
    auto = model.solve_points(near, np.zeros(2), seed)
    model.closed_form = None
    assert np.abs(model.solve_points(near, np.zeros(2), seed)[0] - auto[0]).max() < 1e-6


def test_the_kinematics_self_checks_refuse_a_model_that_disagrees() -> None:
    """Both fast paths check themselves against Pinocchio at the probe configurations."""
    import dataclasses

    from keymps.robot.batch_fk import BatchKinematics
    from keymps.robot.closed_form import ClosedFormIk
    from keymps.robot.probes import probe_configurations

    probes = probe_configurations(64, 6)
    assert probes.shape == (64, 6) and np.abs(probes).max() < math.pi
    # spread: every joint's range is covered, no two probes alike
    for column in probes.T:
        assert np.histogram(column, bins=8, range=(-math.pi, math.pi))[0].min() >= 4
    assert np.array_equal(probes, probe_configurations(64, 6))

    model = RobotModel("ur3", tool=BUILTIN_TOOLS["knife"])
    base = model.base_in_board.homogeneous
    assert ClosedFormIk.for_model(model.arm, base, model.fk) is not None
    longer = dataclasses.replace(model.arm, forearm=model.arm.forearm + 1e-6)
    assert ClosedFormIk.for_model(longer, base, model.fk) is None
    batch = BatchKinematics.for_model(model.model)
    assert batch is not None
    joints = list(batch.joints)
    joints[3] = dataclasses.replace(joints[3], translation=joints[3].translation + [1e-6, 0, 0])
    assert not BatchKinematics(tuple(joints))._agrees_with(model.model)


def test_batched_forward_kinematics_is_pinocchios() -> None:
    rng = np.random.default_rng(RNG_SEED + 2)
    for _ in range(3):
        model = random_model(rng)
        assert model.batch is not None
        qs = rng.uniform(-2 * math.pi, 2 * math.pi, (5000, 6))  # more than one chunk
        positions, rotations = model.tool_poses(qs)
        expected_p, expected_r = model.pinocchio_tool_poses(qs)
        assert np.abs(positions - expected_p).max() < 1e-12
        assert np.abs(rotations - expected_r).max() < 1e-12
        origins = model.joint_origins_many(qs[:200])
        assert np.abs(origins - np.array([model.joint_origins(q) for q in qs[:200]])).max() < 1e-12
        # one pass for the safety check: the very same numbers as the two passes
        together = model.tool_poses_and_joint_origins(qs)
        apart = (positions, rotations, model.joint_origins_many(qs))
        assert all(np.array_equal(a, b) for a, b in zip(together, apart, strict=True))
        for some in (qs[:4096], qs):  # one chunk of batch FK, and more
            got_p, got_x = model.tool_positions_and_x_axes(some)
            assert np.array_equal(got_p, positions[: len(some)])
            assert np.array_equal(got_x, rotations[: len(some), :, 0])


def test_ruckig_phases_in_numpy_match_at_time() -> None:
    from keymps.motion.timing import Limits, _profile, _sample_profile, _sample_profile_by_calls

    rng = np.random.default_rng(RNG_SEED + 3)
    for _ in range(60):
        limits = Limits(rng.uniform(0.005, 0.3), rng.uniform(0.05, 3.0), rng.uniform(0.5, 60.0))
        profile, duration = _profile(float(rng.uniform(1e-5, 0.4)), limits, 1 / 125)
        times = np.append(np.arange(0.0, duration + 0.01, 0.002), [duration, 0.0])
        fast = np.array(_sample_profile(profile, times))
        reference = np.array(_sample_profile_by_calls(profile, times))
        assert np.abs(fast - reference).max() < 1e-12


def test_sampling_many_profiles_at_once_is_each_profile_alone() -> None:
    from keymps.motion.timing import Limits, _profile, _sample_profile, _sample_profiles

    rng = np.random.default_rng(RNG_SEED + 21)
    profiles, times = [], []
    for _ in range(40):
        limits = Limits(rng.uniform(0.005, 0.3), rng.uniform(0.05, 3.0), rng.uniform(0.5, 60.0))
        profile, duration = _profile(float(rng.uniform(1e-5, 0.4)), limits, 1 / 125)
        profiles.append(profile)
        times.append(np.append(np.arange(0.0, duration + 0.01, 0.001), [duration, 0.0]))
    together = np.array(_sample_profiles(profiles, times))
    alone = np.concatenate(
        [np.array(_sample_profile(p, t)) for p, t in zip(profiles, times, strict=True)], axis=1
    )
    assert together.tobytes() == alone.tobytes()


def test_the_numpy_spline_is_scipys_not_a_knot_spline() -> None:
    from scipy.interpolate import CubicSpline as ScipySpline

    from keymps.motion.spline import CubicSpline

    rng = np.random.default_rng(RNG_SEED + 4)
    sizes = [2, 3, 4, 5, 17, 277, 900]
    for n in sizes:
        x = np.concatenate([[0.0], np.cumsum(rng.uniform(1e-5, 3e-3, n - 1))])
        y = np.cumsum(rng.normal(0, 0.01, (n, 6)), axis=0)
        at = np.concatenate([x, rng.uniform(-1e-3, x[-1] + 1e-3, 400)])
        ours, theirs = CubicSpline(x, y), ScipySpline(x, y, axis=0)
        together = ours.with_derivatives(at)
        rates = ours.derivatives(at)
        assert np.array_equal(rates[0], together[1]) and np.array_equal(rates[1], together[2])
        for nu in range(4):
            scale = max(1.0, float(np.abs(theirs(at, nu)).max()))
            assert np.abs(ours(at, nu) - theirs(at, nu)).max() / scale < 1e-11, (n, nu)
            if nu < 3:
                assert np.array_equal(together[nu], ours(at, nu))


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


@pytest.mark.parametrize("task_file", ["cake_icing.yaml", "object_cutting.yaml"])
def test_shipped_runs_are_unchanged_by_the_closed_form(
    task_file: str, tmp_path: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """IK, timing, validation and the simulated outcome with the closed form, and with every
    point solved iteratively as before."""
    from pathlib import Path

    from keymps import load_task, run_task
    from keymps.robot import closed_form

    task = load_task(Path(__file__).parents[1] / "tasks" / task_file)
    fast = run_task(task, out=tmp_path / "fast", rerun="off", backend="offline", executor="sim")
    monkeypatch.setattr(closed_form.ClosedFormIk, "for_model", classmethod(lambda *a: None))
    slow = run_task(task, out=tmp_path / "slow", rerun="off", backend="offline", executor="sim")
    for a, b in zip(fast.stages.solve.pieces, slow.stages.solve.pieces, strict=True):
        assert np.abs(a - b).max() < 1e-6
    fast_t, slow_t = fast.stages.time, slow.stages.time
    assert np.array_equal(fast_t.t, slow_t.t)
    assert np.abs(fast_t.q - slow_t.q).max() < 1e-5
    assert np.abs(fast_t.tool_xyz - slow_t.tool_xyz).max() < 1e-6
    fast_v, slow_v = fast.stages.check.report, slow.stages.check.report
    assert fast_v.ok == slow_v.ok
    for name, value in slow_v.figures.items():
        assert fast_v.figures[name] == pytest.approx(value, rel=1e-3, abs=1e-6), name
    assert fast.stages.execute.ok == slow.stages.execute.ok


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


def test_side_bands_in_windows_match_the_whole_image_computation() -> None:
    from keymps.perception.search_area import SearchArea

    rng = np.random.default_rng(RNG_SEED + 12)
    for trial in range(20):
        width, height = int(rng.integers(40, 300)), int(rng.integers(40, 300))
        if trial % 4 == 0:
            polygon = None  # the whole image
        else:
            count = int(rng.integers(3, 8))
            angles = np.sort(rng.uniform(0, 2 * math.pi, count))
            radius = rng.uniform(0.3, 0.7, count) * min(width, height) / 2
            polygon = [
                (width / 2 + r * math.cos(a) + rng.uniform(-5, 5), height / 2 + r * math.sin(a))
                for r, a in zip(radius, angles, strict=True)
            ]  # a corner may lie outside the image
        area = SearchArea.of((width, height), polygon)
        band_width = float(rng.choice([0.5, 1.5, 2.0, 3.7, 12.0]))
        for got, side in zip(
            area.side_bands(band_width),
            zip(area.polygon, np.roll(area.polygon, -1, axis=0), strict=True),
            strict=True,
        ):
            assert np.array_equal(got, _whole_image_band(area.mask, *side, band_width))


def _whole_image_band(mask: np.ndarray, a: np.ndarray, b: np.ndarray, width_px: float) -> Any:
    """One side's band computed over every pixel (as side_bands did before its windows)."""
    height, width = mask.shape
    cols = np.arange(width, dtype=np.float32)[None, :] + 0.5
    rows = np.arange(height, dtype=np.float32)[:, None] + 0.5
    edge = b - a
    length = max(float(np.hypot(*edge)), 1e-9)
    t = np.clip(((cols - a[0]) * edge[0] + (rows - a[1]) * edge[1]) / length**2, 0, 1)
    dx, dy = cols - (a[0] + t * edge[0]), rows - (a[1] + t * edge[1])
    return mask & (dx * dx + dy * dy <= width_px * width_px)


def test_cut_length_from_runs_matches_all_blade_samples_at_once() -> None:
    from keymps.default_plugins.sim.cut_sweep import Footprint, covered_length

    rng = np.random.default_rng(RNG_SEED + 14)
    for trial in range(40):
        outlines = []
        for _ in range(int(rng.choice([1, 1, 2, 3]))):  # several objects: holes between them
            angles = np.sort(rng.uniform(0, 2 * math.pi, int(rng.integers(3, 60))))
            radius = rng.uniform(0.01, 0.09, len(angles))  # ragged: concave outlines
            centre = np.array([0.15, 0.1]) + rng.normal(0, 0.04, 2)
            outlines.append(
                centre + radius[:, None] * np.column_stack([np.cos(angles), np.sin(angles)])
            )
        footprint = Footprint(outlines if len(outlines) > 1 else outlines[0]) if trial % 4 else None
        count = int(rng.integers(1, 400))
        heading = rng.uniform(0, math.pi)
        along = np.array([math.cos(heading), math.sin(heading)])
        tips = np.array([0.15, 0.1]) + np.outer(rng.uniform(-0.1, 0.1, count), along)
        tips += rng.normal(0, float(rng.choice([0.0, 1e-4, 3e-3])), tips.shape)
        blade = float(rng.choice([0.0005, 0.02, 0.16]))
        turn = heading + rng.normal(0, float(rng.choice([0.0, 0.05, 0.5])), count)
        backwards = np.column_stack([np.cos(turn), np.sin(turn)])
        segments = np.stack([tips, tips - blade * backwards], axis=1)
        got = covered_length(segments, footprint)
        assert got == _covered_length_at_once(segments, footprint)


def _covered_length_at_once(segments: np.ndarray, footprint: Any) -> float:
    """covered_length as it was: every blade sample tested and projected on the SVD's axis,
    np.unique of the bins."""
    from keymps.default_plugins.sim.cut_sweep import FOOTPRINT_CELL_M, LENGTH_BIN_M

    longest = float(np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1).max())
    fractions = np.linspace(0.0, 1.0, max(2, math.ceil(2 * longest / LENGTH_BIN_M) + 1))
    starts, ends = segments[:, None, 0], segments[:, None, 1]
    points = (starts + fractions[None, :, None] * (ends - starts)).reshape(-1, 2)
    if footprint is not None:
        cells = np.floor((points - footprint.origin) / FOOTPRINT_CELL_M)
        rows, cols = footprint.mask.shape
        ok = (cells[:, 0] >= 0) & (cells[:, 0] < cols) & (cells[:, 1] >= 0) & (cells[:, 1] < rows)
        inside = np.zeros(len(cells), dtype=bool)
        cells = cells[ok].astype(np.intp)
        inside[ok] = footprint.mask[cells[:, 1], cells[:, 0]] > 0
        points = points[inside]
    if len(points) < 2:
        return 0.0
    centred = points - points.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    return float(len(np.unique(np.floor(centred @ axis / LENGTH_BIN_M))) * LENGTH_BIN_M)


@pytest.mark.parametrize("make_path", [ring_of_dots, radial_cuts])
def test_densifying_all_parts_at_once_matches_part_by_part(make_path: Any) -> None:
    from keymps.motion.strokes import _densify, _densify_all

    rng = np.random.default_rng(RNG_SEED + 15)
    compared = 0
    for _ in range(4):
        model = random_model(rng)
        tool_path = make_path(center=(0.15 + rng.uniform(-0.01, 0.01), 0.09))
        joints, _ = _solve(model, tool_path)
        if joints is None:
            continue
        parts = []
        for piece, qs in zip(tool_path.pieces, joints.pieces, strict=True):
            cut = int(rng.integers(1, len(qs))) if len(qs) > 2 else len(qs) - 1
            parts.append((piece.points[: cut + 1], piece.yaw[: cut + 1], qs[: cut + 1]))
            if cut < len(qs) - 1:  # a corner: the next part starts where this one ends
                parts.append((piece.points[cut:], piece.yaw[cut:], qs[cut:]))
        together = _densify_all(model, parts)
        one_by_one = [_densify(model, p, y, q) for p, y, q in parts]
        for got, want in zip(together, one_by_one, strict=True):
            for a, b in zip(got, want, strict=True):
                assert a.shape == b.shape and np.abs(a - b).max() < 1e-12
        compared += 1
    assert compared >= 2


def _generated_strokes(
    rng: np.random.Generator, count: int
) -> list[tuple[RobotModel, ToolPath, Any]]:
    """(model, tool path, strokes) of varied paths, with split halves (shifted splines) among them."""
    from keymps.motion.strokes import split_stroke, split_strokes

    cases = []
    while len(cases) < count:
        model = random_model(rng)
        make_path = ring_of_dots if rng.random() < 0.5 else radial_cuts
        tool_path = make_path(center=(0.15 + rng.uniform(-0.01, 0.01), 0.09))
        joints, _ = _solve(model, tool_path)
        if joints is None:
            continue
        strokes = split_strokes(model, tool_path, joints)
        for stroke in list(strokes[:: max(1, len(strokes) // 4)]):
            halves = split_stroke(stroke, float(rng.uniform(0, stroke.length)))
            if halves is not None:
                strokes.extend(halves)
                quarters = split_stroke(halves[1], float(rng.uniform(0, halves[1].length)))
                strokes.extend(quarters or ())  # a shift of a shift
        cases.append((model, tool_path, strokes))
    return cases


def test_timing_all_strokes_at_once_matches_stroke_by_stroke(monkeypatch: Any) -> None:
    from keymps.motion.spline import SplineTable
    from keymps.motion.timing import Limits, time_stroke, time_strokes_at_once

    monkeypatch.setattr(SplineTable, "CHUNK", 257)  # many chunk boundaries inside strokes
    rng = np.random.default_rng(RNG_SEED + 16)
    slowed = stopped = 0
    for model, _, strokes in _generated_strokes(rng, 3):
        # fast tool limits, so that the joint limits slow some strokes down (retimes)
        tool_limits = Limits(math.inf, float(rng.uniform(1, 30)), float(rng.uniform(20, 400)))
        period = 1 / float(rng.choice([125, 500, 1000]))
        together = time_strokes_at_once(model, strokes, tool_limits, period)
        for stroke, got in zip(strokes, together, strict=True):
            try:
                want = time_stroke(model, stroke, tool_limits, period)
            except KeympsError as error:
                assert isinstance(got, KeympsError) and str(got) == str(error)
                continue
            assert not isinstance(got, KeympsError)
            assert (got.duration, got.limits, got.slowdown, got.worst_s) == (
                want.duration,
                want.limits,
                want.slowdown,
                want.worst_s,
            )
            slowed += want.slowdown > 1
            stopped += want.worst_s != 0.0
    assert slowed >= 3 and stopped >= 1, (slowed, stopped)


def test_sampling_all_strokes_at_once_matches_stroke_by_stroke() -> None:
    from keymps.motion.timing import (
        Limits,
        _joint_motion,
        _planned_points,
        _sample_profile,
        sample_trajectory,
        time_strokes_at_once,
    )

    rng = np.random.default_rng(RNG_SEED + 17)
    for model, tool_path, strokes in _generated_strokes(rng, 2):
        rate = float(rng.choice([125, 500]))
        timed = time_strokes_at_once(model, strokes, Limits(math.inf, 2.0, 20.0), 1 / rate)
        timed = [item for item in timed if not isinstance(item, KeympsError)]
        got = sample_trajectory(model, tool_path, timed, rate)
        parts = []
        for number, item in enumerate(timed):
            steps = round(item.duration * rate) + (number == len(timed) - 1)
            s, sd, sdd = _sample_profile(item.profile, np.arange(steps) * (1 / rate))
            q, qd, qdd = _joint_motion(item.stroke, s, sd, sdd)
            parts.append((q, qd, qdd, _planned_points(item.stroke, s)))
        q, qd, qdd, xyz = (np.concatenate(column) for column in zip(*parts, strict=True))
        qd[[0, -1]] = qdd[[0, -1]] = 0.0
        for a, b in ((got.q, q), (got.qd, qd), (got.qdd, qdd), (got.tool_xyz, xyz)):
            assert a.shape == b.shape and a.tobytes() == b.tobytes()


def test_spline_table_is_each_spline_bit_for_bit(monkeypatch: Any) -> None:
    from keymps.motion.spline import CubicSpline, SplineTable

    monkeypatch.setattr(SplineTable, "CHUNK", 97)
    rng = np.random.default_rng(RNG_SEED + 18)
    splines = []
    for n in [2, 3, 4, 5, 17, 277, 2, 60]:
        x = np.concatenate([[0.0], np.cumsum(rng.uniform(1e-5, 3e-3, n - 1))])
        splines.append(CubicSpline(x, np.cumsum(rng.normal(0, 0.01, (n, 6)), axis=0)))
    table = SplineTable(splines)
    which = [int(k) for k in rng.integers(0, len(splines), 30)]
    at = [
        np.sort(rng.uniform(-1e-3, splines[k].x[-1] + 1e-3, int(rng.integers(1, 300))))
        for k in which
    ]
    flat = np.concatenate(at)
    got = [np.zeros((len(flat), 6)) for _ in range(3)]
    rows = table.intervals(which, flat, [len(a) for a in at])
    for part, value, first, second in table.chunks(flat, rows):
        for out, columns in zip(got, (value, first, second), strict=True):
            out[part] = columns.T
    want = [
        np.concatenate(c)
        for c in zip(
            *(splines[k].with_derivatives(a) for k, a in zip(which, at, strict=True)), strict=True
        )
    ]
    for a, b in zip(got, want, strict=True):
        assert a.tobytes() == b.tobytes()


def _significant_points_one_by_one(points: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """The straightforward `_significant_points`: every point's distance from the last kept."""
    from keymps.motion.strokes import MIN_STEP_M, YAW_RADIUS_M

    geometry = np.column_stack([points, YAW_RADIUS_M * yaw])
    kept = [0]
    for i in range(1, len(points)):
        if np.linalg.norm(geometry[i] - geometry[kept[-1]]) >= MIN_STEP_M:
            kept.append(i)
    if len(kept) > 1:
        kept[-1] = len(points) - 1
    return np.array(kept)


def _corner_indexes_point_by_point(points: np.ndarray, yaw: np.ndarray) -> list[int]:
    """The straightforward `_corner_indexes` loop over every point (the same directions)."""
    from keymps.motion import strokes

    geometry = np.column_stack([points, strokes.YAW_RADIUS_M * yaw])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(geometry, axis=0), axis=1))])
    n = len(points)
    if n < 3 or arc[-1] <= 0:
        return []
    chord = strokes.CORNER_CHORD_M
    before = np.clip(np.searchsorted(arc, arc - chord, side="right") - 1, 0, n - 1)
    after = np.clip(np.searchsorted(arc, arc + chord, side="left"), 0, n - 1)
    incoming, outgoing = geometry - geometry[before], geometry[after] - geometry
    norms = np.linalg.norm(incoming, axis=1) * np.linalg.norm(outgoing, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.where(norms > 1e-18, (incoming * outgoing).sum(axis=1) / norms, 1.0)
    sharp = cosine < math.cos(strokes.CORNER_ANGLE_RAD)
    sharp[[0, -1]] = False
    corners, index = [], 0
    while index < n:
        if not sharp[index]:
            index += 1
            continue
        end = index
        while end + 1 < n and sharp[end + 1] and arc[end + 1] - arc[index] <= 2 * chord:
            end += 1
        middle = (arc[index] + arc[end]) / 2
        distance = np.abs(arc[index : end + 1] - middle)  # the first of those equally near
        corners.append(index + int(np.flatnonzero(distance <= distance.min() + strokes.TIE_M)[0]))
        index = end + 1
    return corners


def _wandering_path(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Runs of long steps, dwells jittering by up to 0.2 mm, steps of exactly MIN_STEP_M,
    reversals and turns of the tool: what rollouts and planners hand the timing."""
    from keymps.motion.strokes import MIN_STEP_M

    parts, yaws = [np.zeros((1, 3))], [np.zeros(1)]
    for _ in range(int(rng.integers(3, 12))):
        kind = rng.integers(0, 4)
        count = int(rng.integers(2, 90))
        if kind == 0:  # a run of long steps in one direction
            step = rng.normal(0, 1, 3)
            step *= rng.uniform(3e-4, 3e-3) / np.linalg.norm(step)
            move = np.cumsum(np.tile(step, (count, 1)), axis=0)
        elif kind == 1:  # a dwell
            move = rng.uniform(-2e-4, 2e-4, (count, 3))
        elif kind == 2:  # steps of exactly the threshold along one axis
            move = np.zeros((count, 3))
            move[:, int(rng.integers(0, 3))] = MIN_STEP_M * np.arange(1, count + 1)
        else:  # back and forth
            move = np.zeros((count, 3))
            move[:, 0] = rng.uniform(1e-4, 2e-3) * np.sin(np.arange(count) * rng.uniform(0.3, 3))
        parts.append(parts[-1][-1] + move)
        turn = rng.uniform(-0.02, 0.02, count) if rng.random() < 0.3 else np.zeros(count)
        yaws.append(yaws[-1][-1] + np.cumsum(turn))
    return np.concatenate(parts), np.concatenate(yaws)


def test_dropping_dwell_points_by_runs_matches_point_by_point() -> None:
    from keymps.motion.strokes import _corner_indexes_all, _significant_points_all

    rng = np.random.default_rng(RNG_SEED + 19)
    for _ in range(60):
        paths = [_wandering_path(rng) for _ in range(int(rng.integers(1, 8)))]
        every_kept = _significant_points_all(paths)  # all parts at once
        kept_paths = [(p[kept], y[kept]) for (p, y), kept in zip(paths, every_kept, strict=True)]
        every_corner = _corner_indexes_all(kept_paths)
        for (points, yaw), kept, corners in zip(paths, every_kept, every_corner, strict=True):
            assert np.array_equal(kept, _significant_points_one_by_one(points, yaw))
            assert corners == _corner_indexes_point_by_point(points[kept], yaw[kept])


def test_splines_side_by_side_are_the_splines_one_by_one() -> None:
    from keymps.motion.spline import CubicSpline, many_splines

    rng = np.random.default_rng(RNG_SEED + 20)
    for _ in range(40):
        knots, values = [], []
        for _ in range(int(rng.integers(1, 25))):
            n = int(rng.choice([2, 3, 4, 5, int(rng.integers(6, 250))]))
            knots.append(np.concatenate([[0.0], np.cumsum(rng.uniform(1e-5, 3e-3, n - 1))]))
            y = np.cumsum(rng.normal(0, 0.01, (n, 6)), axis=0)
            if rng.random() < 0.2:
                y[:, int(rng.integers(0, 6))] = 0.0  # a joint that does not move (zero slopes)
            values.append(y)
        together = many_splines(knots, values)
        for spline, x, y in zip(together, knots, values, strict=True):
            alone = CubicSpline(x, y)
            assert spline.c.tobytes() == alone.c.tobytes() and np.array_equal(spline.x, alone.x)


def test_inserting_knots_in_all_parts_at_once_matches_part_by_part() -> None:
    from keymps.motion.strokes import _dense_points, _dense_points_all, _every_few, _every_few_all

    rng = np.random.default_rng(RNG_SEED + 22)
    for _ in range(60):
        parts = []
        for _ in range(int(rng.integers(1, 12))):
            points, yaw = _wandering_path(rng)
            if rng.random() < 0.3:  # gaps of up to a few centimetres (travel moves)
                points = points * rng.uniform(5, 40)
            parts.append((points, yaw))
        together = _dense_points_all(parts)
        for (points, yaw), got in zip(parts, together, strict=True):
            want = _dense_points(points, yaw)
            for a, b in zip(got, want, strict=True):
                assert a.shape == b.shape and a.tobytes() == b.tobytes()
        for (points, yaw), got in zip(parts, _every_few_all(parts), strict=True):
            want = _every_few(points, yaw)
            assert got.dtype == want.dtype and np.array_equal(got, want)


def test_inverse_dh_links_are_the_inverted_links_bit_for_bit() -> None:
    from keymps.robot.closed_form import _inverse, dh_link, inverse_dh_link

    rng = np.random.default_rng(RNG_SEED + 23)
    for _ in range(4):
        arm = random_model(rng).closed_form.arm  # type: ignore[union-attr]
        theta = np.concatenate(
            [rng.uniform(-2 * math.pi, 2 * math.pi, 3000), [0.0, -0.0, math.pi, -math.pi / 2]]
        )
        for i in range(6):
            assert (
                inverse_dh_link(theta, i, arm).tobytes()
                == _inverse(dh_link(theta, i, arm)).tobytes()
            )


class _OtherSpline:
    """A q(s) that is no keymps CubicSpline (a plugin's, say): evaluated stroke by stroke."""

    def __init__(self, spline: Any):
        self.spline = spline

    def derivatives(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.spline.derivatives(s)  # type: ignore[no-any-return]

    def with_derivatives(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.spline.with_derivatives(s)  # type: ignore[no-any-return]


def test_strokes_of_other_splines_are_timed_and_sampled_alike() -> None:
    import dataclasses

    from keymps.motion.timing import Limits, sample_trajectory, time_stroke, time_strokes_at_once

    rng = np.random.default_rng(RNG_SEED + 24)
    for model, tool_path, strokes in _generated_strokes(rng, 1):
        others = [dataclasses.replace(s, q_of_s=_OtherSpline(s.q_of_s)) for s in strokes[:12]]
        limits = Limits(math.inf, 8.0, 150.0)
        together = time_strokes_at_once(model, others, limits, 1 / 125)
        for stroke, got in zip(others, together, strict=True):
            want = time_stroke(model, stroke, limits, 1 / 125)
            assert not isinstance(got, KeympsError)
            assert (got.duration, got.limits, got.slowdown) == (
                want.duration,
                want.limits,
                want.slowdown,
            )
        timed = [item for item in together if not isinstance(item, KeympsError)]
        direct = [
            dataclasses.replace(item, stroke=s) for item, s in zip(timed, strokes[:12], strict=True)
        ]
        a = sample_trajectory(model, tool_path, timed, 125.0)
        b = sample_trajectory(model, tool_path, direct, 125.0)
        assert a.q.tobytes() == b.q.tobytes() and a.qdd.tobytes() == b.qdd.tobytes()


def _random_board_model(rng: np.random.Generator) -> Any:
    from keymps.perception.board_model import BoardModel

    degree = int(rng.integers(0, 3))
    terms = (degree + 1) * (degree + 2) // 2
    coefficients = rng.normal(0, [[30, 10, 10]], (terms, 3)).astype(np.float32)
    coefficients[0] += np.float32([60, 5, 10])
    size = (int(rng.integers(20, 400)), int(rng.integers(20, 300)))
    return BoardModel(coefficients, degree, size, 0, 0.0)


def test_board_model_planes_are_the_term_by_term_image() -> None:
    from keymps.perception.board_model import _exponents

    rng = np.random.default_rng(RNG_SEED + 20)
    for _ in range(30):
        model = _random_board_model(rng)
        width, height = model.size_px
        x, y = model._normalized(
            np.arange(width, dtype=np.float32)[None, :],
            np.arange(height, dtype=np.float32)[:, None],
        )
        expected = np.zeros((height, width, 3), np.float32)  # as BoardModel.image() was
        for (i, j), weights in zip(_exponents(model.degree), model.coefficients, strict=True):
            term = x**i * y**j
            for channel in range(3):
                expected[..., channel] += weights[channel] * term
        assert np.array_equal(model.image(), expected)
        assert np.array_equal(np.moveaxis(model.planes(), 0, -1), expected)
        used = rng.normal(0, 50, (3, height, width)).astype(np.float32)  # an earlier surface
        assert model.planes(out=used) is used
        assert np.array_equal(np.moveaxis(used, 0, -1), expected)
        described = model.describe(model.planes())
        mean = expected.reshape(-1, 3).mean(axis=0)
        assert described["mean_lab"] == [round(float(v), 2) for v in mean]


def test_distance_to_board_in_buffers_is_the_formula() -> None:
    from keymps.perception.board_model import distance_to_board, lab_planes

    rng = np.random.default_rng(RNG_SEED + 21)
    for _ in range(30):
        shape = (int(rng.integers(5, 200)), int(rng.integers(5, 200)), 3)
        lab = (rng.normal(0, [30, 20, 20], shape) + [50, 0, 0]).astype(np.float32)
        model = (rng.normal(0, [20, 10, 10], shape) + [55, 3, 8]).astype(np.float32)
        model[..., 0][rng.random(shape[:2]) < 0.05] = -20.0  # where max(L + 16, 1) binds
        shadow = float(rng.choice([0.0, 0.5, rng.uniform(0, 0.99)]))
        # the formula as distance_to_board computed it, on H x W x 3 arrays
        lightness = lab[..., 0] - model[..., 0]
        ratio = np.clip((lab[..., 0] + 16.0) / np.maximum(model[..., 0] + 16.0, 1.0), 0.0, 1.0)
        da = lab[..., 1] - ratio * model[..., 1]
        db = lab[..., 2] - ratio * model[..., 2]
        weight = np.where(lightness < 0, 1.0 - shadow, 1.0).astype(np.float32)
        expected = np.sqrt((weight * lightness) ** 2 + da**2 + db**2)
        got = distance_to_board(lab_planes(lab), lab_planes(model), shadow)
        assert got.dtype == np.float32
        assert np.array_equal(got, expected)


def test_board_fit_by_index_is_the_fit_by_mask() -> None:
    from keymps.perception.board_model import BoardModel, _monomials, fit_board

    rng = np.random.default_rng(RNG_SEED + 22)
    for trial in range(24):
        height, width = int(rng.integers(30, 300)), int(rng.integers(30, 400))
        lab = (rng.normal(0, [3, 2, 2], (height, width, 3)) + [70, 4, 12]).astype(np.float32)
        lab[rng.random((height, width)) < 0.1] += np.float32([-30, 20, 5])  # an object's pixels
        where = rng.random((height, width)) < rng.uniform(0.02, 1.0)
        degree = trial % 3
        # the fit as it was: np.nonzero, index pairs, boolean masks, np.linalg.norm
        rows, cols = np.nonzero(where)
        if len(rows) > 12_000:
            keep = np.linspace(0, len(rows) - 1, 12_000).astype(int)
            rows, cols = rows[keep], cols[keep]
        values = lab[rows, cols].astype(np.float64)
        probe = BoardModel(np.zeros((1, 3)), degree, (width, height), 0, 0.0)
        design = _monomials(*probe._normalized(cols.astype(float), rows.astype(float)), degree)
        residual = np.linalg.norm(values - np.median(values, axis=0), axis=1)
        inliers = residual <= 3.0 * float(np.median(residual)) + 1.0
        coefficients = np.zeros((design.shape[1], 3))
        for _ in range(3):
            if inliers.sum() < design.shape[1] * 4:
                break
            used = design[inliers]
            coefficients = np.linalg.solve(
                used.T @ used + 1e-9 * np.eye(used.shape[1]), used.T @ values[inliers]
            )
            residual = np.linalg.norm(values - design @ coefficients, axis=1)
            inliers = residual <= 3.0 * float(np.median(residual[inliers])) + 1.0
        got = fit_board(lab, where, degree)
        assert np.array_equal(got.coefficients, coefficients.astype(np.float32))
        assert got.samples == int(inliers.sum())
        expected_residual = float(np.median(residual[inliers])) if inliers.any() else 0.0
        assert got.residual == expected_residual


def test_search_areas_are_shared_read_only_and_their_bands_are_the_direct_ones() -> None:
    from keymps.perception.search_area import SearchArea

    rng = np.random.default_rng(RNG_SEED + 23)
    for trial in range(12):
        width, height = int(rng.integers(40, 300)), int(rng.integers(40, 300))
        polygon = None
        if trial % 3:
            polygon = [
                (float(rng.uniform(0, width / 3)), float(rng.uniform(2 * height / 3, height))),
                (
                    float(rng.uniform(2 * width / 3, width)),
                    float(rng.uniform(2 * height / 3, height)),
                ),
                (float(rng.uniform(2 * width / 3, width)), float(rng.uniform(0, height / 3))),
                (float(rng.uniform(0, width / 3)), float(rng.uniform(0, height / 3))),
            ]
        area = SearchArea.of((width, height), polygon)
        assert SearchArea.of((width, height), polygon) is area
        assert not area.mask.flags.writeable
        for band_width in (int(rng.integers(1, 12)), 2):
            padded = np.pad(area.mask.astype(np.uint8), 1)
            distance = cv2_distance(padded)[1:-1, 1:-1]
            assert np.array_equal(
                area.border_band(band_width), area.mask & (distance <= band_width)
            )
            with pytest.raises(ValueError):
                area.border_band(band_width)[0, 0] = True
        first = area.side_bands(3.5)
        assert all(np.array_equal(a, b) for a, b in zip(first, area._side_bands(3.5), strict=True))


def cv2_distance(padded: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.distanceTransform(padded, cv2.DIST_L2, 3)


def test_region_counts_in_the_box_are_the_whole_image_counts() -> None:
    import cv2

    from keymps.default_plugins.board_detector import BoardDetector
    from keymps.perception.search_area import SearchArea

    rng = np.random.default_rng(RNG_SEED + 24)
    checked = 0
    for _ in range(12):
        width, height = int(rng.integers(60, 300)), int(rng.integers(60, 240))
        area = SearchArea.of((width, height), None)
        bands = [
            band & ~out for band, out in zip(area.side_bands(3.5), area.side_bands(2), strict=True)
        ]
        blobs = np.zeros((height, width), np.uint8)
        for _ in range(int(rng.integers(1, 5))):  # blobs, some over the image's border
            centre = (int(rng.integers(-10, width + 10)), int(rng.integers(-10, height + 10)))
            axes = (int(rng.integers(5, width // 2)), int(rng.integers(5, height // 2)))
            cv2.ellipse(blobs, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        mask = (blobs > 0) & (rng.random((height, width)) < 0.97)  # with holes
        distance = rng.uniform(0, 40, (height, width)).astype(np.float32)
        for region in BoardDetector()._regions(mask, distance, area, bands, 30):
            inside = region.mask  # whole image, as the counts were taken before
            assert region.coverage == float(inside.sum()) / area.pixels
            names = area.side_names()
            assert region.sides == tuple(
                n for n, b in zip(names, bands, strict=True) if (inside & b).any()
            )
            assert region.along == max(
                float((inside & b).sum()) / max(int(b.sum()), 1) for b in bands
            )
            assert region.contrast == float(np.median(distance[inside & mask]))
            checked += 1
    assert checked >= 12


def test_run_folder_png_keeps_every_pixel(tmp_path: Any) -> None:
    import cv2

    from keymps.run import write_image

    rng = np.random.default_rng(RNG_SEED + 16)
    for trial in range(6):
        height, width = (int(v) for v in rng.integers(1, 400, 2))
        image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        if trial % 2:  # flat areas and edges, as drawn scenes have
            image[: height // 2] = image[0, 0]
        path = write_image(tmp_path / f"{trial}.png", image)
        assert np.array_equal(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), image)


def test_painting_cuts_on_covered_pixels_matches_blending_the_whole_image() -> None:
    from keymps.default_plugins.sim.executor import _paint_cuts

    rng = np.random.default_rng(RNG_SEED + 17)
    shift, painted = 4, 0
    for trial in range(8):
        height, width = (int(v) for v in rng.integers(50, 300, 2))
        scale = float(rng.uniform(1500, 3000))  # pixels per metre

        def pixels(xy: np.ndarray, scale: float = scale) -> np.ndarray:
            return np.round(np.asarray(xy).reshape(-1, 2) * scale * (1 << shift)).astype(np.int32)

        image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        size = np.array([width, height]) / scale
        sweeps = []
        for _ in range(int(rng.integers(1, 5))):
            tips = rng.uniform(0, 1, (int(rng.integers(2, 60)), 2)) * size
            sweeps.append(np.stack([tips, tips + rng.normal(0, 0.02, tips.shape)], axis=1))
        footprint = None
        if trial % 3:
            angles = np.sort(rng.uniform(0, 2 * math.pi, 12))
            footprint = size / 2 + np.column_stack([np.cos(angles), np.sin(angles)]) * size / 3
        line = int(rng.integers(1, 6))
        got = image.copy()
        _paint_cuts(got, sweeps, footprint, pixels, line, shift)
        assert np.array_equal(got, _paint_whole_image(image, sweeps, footprint, pixels, line))
        painted += not np.array_equal(got, image)
    assert painted >= 6  # (a footprint may happen to clip every cut away)


def _paint_whole_image(
    image: np.ndarray, sweeps: list[np.ndarray], footprint: Any, pixels: Any, width: int
) -> np.ndarray:
    """_paint_cuts as it was: every pixel of the image blended."""
    import cv2

    from keymps.default_plugins.sim.executor import CUT_COLOUR

    covered = np.zeros(image.shape[:2], np.uint8)
    for sweep in sweeps:
        segments = pixels(sweep.reshape(-1, 2)).reshape(-1, 2, 2)
        cv2.polylines(covered, list(segments), False, 255, width, cv2.LINE_AA, 4)
    alpha = covered.astype(np.float32) / 255.0
    if footprint is not None:
        inside = np.zeros(image.shape[:2], np.uint8)
        cv2.fillPoly(inside, [pixels(footprint)], 255, cv2.LINE_AA, 4)
        alpha *= inside.astype(np.float32) / 255.0
    alpha = alpha[:, :, None]
    return np.round(image * (1.0 - alpha) + np.array(CUT_COLOUR) * alpha).astype(np.uint8)


def test_interpolated_cos_sin_by_recurrence_matches_numpy() -> None:
    from keymps.robot.batch_fk import interpolated_cos_sin

    rng = np.random.default_rng(RNG_SEED + 18)
    for substeps in (1, 2, 3, 8, 40):
        speed = float(rng.choice([1e-4, 0.01, 0.3]))  # radians per sample
        qs = np.cumsum(rng.normal(0, speed, (int(rng.integers(2, 400)), 6)), axis=0)
        qs += rng.uniform(-2 * math.pi, 2 * math.pi, 6)
        fractions = np.arange(substeps) / substeps
        between = qs[:-1, None] + fractions[:, None] * (qs[1:] - qs[:-1])[:, None]
        angles = np.concatenate([between.reshape(-1, 6), qs[-1:]]).T
        cos, sin = interpolated_cos_sin(qs, substeps)
        assert np.abs(cos - np.cos(angles)).max() < 1e-14
        assert np.abs(sin - np.sin(angles)).max() < 1e-14


def test_sim_replay_matches_forward_kinematics_of_every_interpolated_sample() -> None:
    from keymps.default_plugins.sim.executor import replay
    from keymps.types import Trajectory

    rng = np.random.default_rng(RNG_SEED + 19)
    for _ in range(6):
        model = random_model(rng)
        rate = float(rng.choice([125.0, 500.0]))
        n = int(rng.integers(2, 700))
        q = np.cumsum(rng.normal(0, 0.004, (n, 6)), axis=0) + rng.uniform(-math.pi, math.pi, 6)
        pieces = np.sort(rng.integers(0, 5, n))
        trajectory = Trajectory(
            np.arange(n) / rate, q, np.zeros((n, 6)), np.zeros((n, 6)),
            rng.uniform(-0.1, 0.3, (n, 3)), pieces, np.where(pieces % 2, "work", "travel"),
            tuple(model.joint_names), rate,
        )  # fmt: skip
        replay_rate = float(rng.choice([250.0, 1000.0, 3000.0]))
        got = replay(model, trajectory, replay_rate)
        # the straightforward replay: every replayed sample's joints, then forward kinematics
        substeps = max(1, math.ceil(replay_rate / rate))
        base = np.append(np.repeat(np.arange(n - 1), substeps), n - 1)
        frac = np.append(np.tile(np.arange(substeps) / substeps, n - 1), 0.0)
        nxt = np.minimum(base + 1, n - 1)
        joints = q[base] + frac[:, None] * (q[nxt] - q[base])
        positions, rotations = model.tool_poses(joints)
        planned = trajectory.tool_xyz
        assert np.array_equal(got.t, trajectory.t[base] + frac / rate)
        assert np.array_equal(
            got.planned_xyz, planned[base] + frac[:, None] * (planned[nxt] - planned[base])
        )
        assert np.array_equal(got.piece_index, pieces[base])
        assert np.array_equal(got.kind, trajectory.kind[base])
        assert np.abs(got.tool_xyz - positions).max() < 1e-13
        x_axis = rotations[:, :2, 0] / np.linalg.norm(rotations[:, :2, 0], axis=1, keepdims=True)
        assert got.tool_x is not None and np.abs(got.tool_x - x_axis).max() < 1e-12


def test_trajectory_csv_in_numpy_is_pythons_formatting_row_by_row() -> None:
    from keymps.motion.trajectory_io import CSV_HEADER, ROW, trajectory_csv
    from keymps.types import Trajectory

    rng = np.random.default_rng(RNG_SEED + 20)
    for trial in range(12):
        n = int(rng.integers(1, 3000))
        scale = float(rng.choice([1e-7, 1e-3, 1.0, 7.0, 1e4]))
        q = rng.normal(0, scale, (n, 6))
        xyz = rng.normal(0, scale, (n, 3))
        t = np.arange(n) / float(rng.choice([125.0, 500.0])) + float(rng.uniform(0, 100))
        # decimal halves (0.1504555 m: within a rounding error of the tie), as icing paths have
        xyz[::3, 0] = (2 * rng.integers(0, 400_000, len(xyz[::3])) + 1) / 2e6
        q[::5, 1] = (2 * rng.integers(-4e9, 4e9, len(q[::5])) + 1) / 2e9
        if trial % 2:  # binary ties, -0, huge, non-finite
            picks = rng.integers(0, n, 12)
            q[picks[:4], rng.integers(0, 6, 4)] = rng.integers(-99, 99, 4) * 2 + 1 / 2**10
            xyz[picks[4:7], rng.integers(0, 3, 3)] = (rng.integers(-9, 9, 3) * 2 + 1) / 2**7
            q[picks[7], 0], q[picks[8], 1], q[picks[9], 2] = -0.0, -1e-13, 3e17
            q[picks[10], 3], xyz[picks[11], 2] = float(rng.choice([np.nan, np.inf, -np.inf])), 1e30
        pieces = np.sort(rng.integers(0, int(rng.choice([3, 40, 20_000])), n))
        kinds = rng.choice(["work", "travel"], n)
        trajectory = Trajectory(
            t, q, q, q, xyz, pieces, kinds, tuple("abcdef"), 125.0
        )  # fmt: skip
        rows = [
            ROW % (*numbers, piece, kind)
            for numbers, piece, kind in zip(
                np.column_stack([t, q, xyz]).tolist(), pieces.tolist(), kinds.tolist(), strict=True
            )
        ]
        assert trajectory_csv(trajectory).decode() == "\n".join([CSV_HEADER, *rows]) + "\n"


def test_blade_positions_are_picked_as_with_numpys_norm_and_union() -> None:
    from keymps.default_plugins.sim.cut_sweep import SWEEP_STEP_M, _every

    rng = np.random.default_rng(RNG_SEED + 22)
    for _ in range(20):
        n = int(rng.integers(2, 5000))
        tip = np.cumsum(rng.normal(0, float(rng.choice([1e-5, 1e-4, 1e-3])), (n, 3)), axis=0)
        far = tip[:, :2] + 0.16 * rng.normal(0, 1, (n, 2)) / 40
        moved = np.maximum(
            np.linalg.norm(np.diff(tip, axis=0), axis=1),
            np.linalg.norm(np.diff(far, axis=0), axis=1),
        )
        bins = np.floor(np.concatenate([[0.0], np.cumsum(moved)]) / SWEEP_STEP_M)
        expected = np.union1d(np.flatnonzero(np.diff(bins, prepend=-1.0) > 0), [n - 1])
        assert np.array_equal(_every(tip, far, SWEEP_STEP_M), expected)


def test_row_norms_are_numpys_norms_to_the_bit() -> None:
    from keymps.robot.safety_geometry import row_norms

    rng = np.random.default_rng(RNG_SEED + 23)
    for columns in (1, 2, 3, 6):
        vectors = rng.normal(0, 1, (20_000, columns)) * 10.0 ** rng.uniform(-12, 3, (20_000, 1))
        assert np.array_equal(row_norms(vectors), np.linalg.norm(vectors, axis=1))


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


def _merging_strokes_pair_by_pair(pairs: np.ndarray, line_width: float) -> Any:
    """merging_strokes as it was: every pair of strokes, points grouped one by one."""
    from keymps.designs.legibility import MERGE_PATH_FACTOR, _cross

    pairs = np.asarray(pairs, float).reshape(-1, 2, 2)
    ends = pairs.reshape(-1, 2)
    tolerance = 1e-6 * max(1.0, float(np.abs(ends).max()))
    nodes: list[np.ndarray] = []
    node_of: list[int] = []
    for point in ends:
        for k, node in enumerate(nodes):
            if np.abs(node - point).max() <= tolerance:
                node_of.append(k)
                break
        else:
            nodes.append(point)
            node_of.append(len(nodes) - 1)
    lengths = np.linalg.norm(pairs[:, 1] - pairs[:, 0], axis=1)
    between = np.full((len(nodes), len(nodes)), np.inf)
    np.fill_diagonal(between, 0.0)
    for k, length in enumerate(lengths):
        a, b = node_of[2 * k], node_of[2 * k + 1]
        between[a, b] = between[b, a] = min(between[a, b], length)
    for k in range(len(nodes)):
        between = np.minimum(between, between[:, k : k + 1] + between[k : k + 1, :])
    step = line_width / 4
    samples = [np.linspace(0.0, 1.0, max(2, math.ceil(n / step) + 1)) for n in lengths]
    points = [p[0] + f[:, None] * (p[1] - p[0]) for p, f in zip(pairs, samples, strict=True)]
    along = [f * n for f, n in zip(samples, lengths, strict=True)]
    best = None
    for i in range(len(pairs)):
        for j in range(i + 1, len(pairs)):
            gaps = np.linalg.norm(points[i][:, None, :] - points[j][None, :, :], axis=2)
            if gaps.min() >= line_width or _cross(pairs[i], pairs[j]):
                continue
            ui, uj = along[i][:, None], along[j][None, :]
            ri, rj = lengths[i] - ui, lengths[j] - uj
            ai, bi, aj, bj = node_of[2 * i], node_of[2 * i + 1], node_of[2 * j], node_of[2 * j + 1]
            path = np.minimum.reduce(
                [ui + between[ai, aj] + uj, ui + between[ai, bj] + rj,
                 ri + between[bi, aj] + uj, ri + between[bi, bj] + rj]
            )  # fmt: skip
            merging = (gaps < line_width) & (path > MERGE_PATH_FACTOR * line_width)
            if merging.any():
                gap = float(gaps[merging].min())
                if best is None or gap < best[0]:
                    a, b = np.argwhere(merging & (gaps == gap))[0]
                    best = (gap, (points[i][a] + points[j][b]) / 2)
    return best


def test_merging_strokes_from_near_boxes_match_every_pair_of_strokes() -> None:
    from keymps.designs.legibility import merging_strokes

    rng = np.random.default_rng(RNG_SEED + 41)
    found = 0
    for case in range(80):
        count = int(rng.integers(1, 25))
        scale = float(rng.choice([1.0, 100.0, 600.0]))  # metres or pixels
        starts = rng.uniform(0, scale, (count, 2))
        lengths = np.where(rng.random(count) < 0.5, 0.0, rng.uniform(0, 0.3 * scale, count))
        turns = rng.uniform(0, 2 * np.pi, count)
        goals = starts + lengths[:, None] * np.column_stack([np.cos(turns), np.sin(turns)])
        pairs = np.stack([starts, goals], axis=1)
        if case % 3 == 0 and count > 2:  # strokes sharing ends: a polyline
            pairs[1:, 0] = pairs[:-1, 1]
        width = float(rng.uniform(0.005, 0.08)) * scale
        got = merging_strokes(pairs, width)
        expected = _merging_strokes_pair_by_pair(pairs, width)
        assert (got is None) == (expected is None)
        if got is not None:
            assert got[0] == expected[0] and np.array_equal(got[1], expected[1])
            found += 1
    assert 10 < found < 70


def test_a_robot_built_again_shares_its_checked_kinematics_and_computes_the_same() -> None:
    """RobotModel keeps the Pinocchio model, batched FK and closed form per arm, base and tool:
    a model built again computes exactly what one built from scratch does."""
    from keymps.robot import model as robot_model

    rng = np.random.default_rng(RNG_SEED + 7)
    for _ in range(3):
        first = random_model(rng)
        again = RobotModel(first.kind, first.base, first.tool)
        assert again.model is first.model and again.data is not first.data
        robot_model._KINEMATICS.clear()
        fresh = RobotModel(first.kind, first.base, first.tool)
        assert fresh.model is not first.model
        qs = rng.uniform(-math.pi, math.pi, (40, 6))
        for q in qs[:5]:
            for got, expected in zip(again.fk(q), fresh.fk(q), strict=True):
                assert np.array_equal(got, expected)
        for got, expected in zip(again.tool_poses(qs), fresh.tool_poses(qs), strict=True):
            assert np.array_equal(got, expected)
        poses = np.zeros((len(qs), 4, 4))
        poses[:, :3, 3], poses[:, :3, :3] = fresh.tool_poses(qs)
        poses[:, 3, 3] = 1.0
        assert again.closed_form is not None and fresh.closed_form is not None
        assert np.array_equal(
            again.closed_form.solve(poses), fresh.closed_form.solve(poses), equal_nan=True
        )
    other_tool = RobotModel(first.kind, first.base, BUILTIN_TOOLS["piping_bag"])
    assert other_tool.model is not first.model
    assert not np.allclose(other_tool.fk(qs[0])[0], first.fk(qs[0])[0])
