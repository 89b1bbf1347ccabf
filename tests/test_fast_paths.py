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
        got = distance_to_polylines(points, which, polylines)
        for index, polyline in enumerate(polylines):
            mine = which == index
            if len(polyline) == 1:
                expected = np.linalg.norm(points[mine] - polyline[0], axis=1)
            else:
                expected = _brute_force(points[mine], polyline)
            assert np.array_equal(got[mine], expected)


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


def test_cut_length_in_chunks_matches_all_blade_samples_at_once() -> None:
    from keymps.default_plugins.sim.cut_sweep import Footprint, covered_length

    rng = np.random.default_rng(RNG_SEED + 14)
    for trial in range(24):
        angles = np.sort(rng.uniform(0, 2 * math.pi, int(rng.integers(3, 60))))
        radius = rng.uniform(0.03, 0.09, len(angles))
        outline = np.column_stack([0.15 + radius * np.cos(angles), 0.1 + radius * np.sin(angles)])
        footprint = Footprint(outline) if trial % 4 else None
        count = int(rng.integers(1, 400))
        heading = rng.uniform(0, math.pi)
        along = np.array([math.cos(heading), math.sin(heading)])
        tips = np.array([0.15, 0.1]) + np.outer(rng.uniform(-0.1, 0.1, count), along)
        tips += rng.normal(0, float(rng.choice([0.0, 1e-4, 3e-3])), tips.shape)
        blade = float(rng.choice([0.0005, 0.02, 0.16]))
        segments = np.stack([tips, tips - blade * along], axis=1)
        got = covered_length(segments, footprint)
        assert got == _covered_length_at_once(segments, footprint)


def _covered_length_at_once(segments: np.ndarray, footprint: Any) -> float:
    """covered_length as it was: every blade sample in one array, np.unique of the bins."""
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
