"""Timing: Ruckig's phases in numpy against `at_time`, the numpy spline against scipy's, every stroke at once against one at a time, and the trajectory file's formatting.

Each fast path is held against the implementation it replaced, on generated inputs."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from helpers.reference_timing import (
    joint_motion,
    planned_points,
    sample_profile,
    time_stroke,
)
from helpers.robot_toolpaths import radial_cuts, ring_of_dots

from keymps.errors import KeympsError
from keymps.robot.model import RobotModel, Tool, solve_path
from keymps.sorted_values import distinct
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


def _solve(model: RobotModel, tool_path: ToolPath) -> tuple[Any, str | None]:
    try:
        return solve_path(model, tool_path), None
    except KeympsError as error:
        return None, str(error)


def test_ruckig_phases_in_numpy_match_at_time() -> None:
    from keymps.motion.timing import Limits, _profile, _sample_profile_by_calls

    rng = np.random.default_rng(RNG_SEED + 3)
    for _ in range(60):
        limits = Limits(rng.uniform(0.005, 0.3), rng.uniform(0.05, 3.0), rng.uniform(0.5, 60.0))
        profile, duration = _profile(float(rng.uniform(1e-5, 0.4)), limits, 1 / 125)
        times = np.append(np.arange(0.0, duration + 0.01, 0.002), [duration, 0.0])
        fast = np.array(sample_profile(profile, times))
        reference = np.array(_sample_profile_by_calls(profile, times))
        assert np.abs(fast - reference).max() < 1e-12


def test_sampling_many_profiles_at_once_is_each_profile_alone() -> None:
    from keymps.motion.timing import Limits, _profile, _sample_profiles

    rng = np.random.default_rng(RNG_SEED + 21)
    profiles, times = [], []
    for _ in range(40):
        limits = Limits(rng.uniform(0.005, 0.3), rng.uniform(0.05, 3.0), rng.uniform(0.5, 60.0))
        profile, duration = _profile(float(rng.uniform(1e-5, 0.4)), limits, 1 / 125)
        profiles.append(profile)
        times.append(np.append(np.arange(0.0, duration + 0.01, 0.001), [duration, 0.0]))
    together = np.array(_sample_profiles(profiles, times))
    alone = np.concatenate(
        [np.array(sample_profile(p, t)) for p, t in zip(profiles, times, strict=True)], axis=1
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
    from keymps.motion.timing import Limits, time_strokes_at_once

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
    from keymps.motion.timing import Limits, sample_trajectory, time_strokes_at_once

    rng = np.random.default_rng(RNG_SEED + 17)
    for model, tool_path, strokes in _generated_strokes(rng, 2):
        rate = float(rng.choice([125, 500]))
        timed = time_strokes_at_once(model, strokes, Limits(math.inf, 2.0, 20.0), 1 / rate)
        timed = [item for item in timed if not isinstance(item, KeympsError)]
        got = sample_trajectory(model, tool_path, timed, rate)
        parts = []
        for number, item in enumerate(timed):
            steps = round(item.duration * rate) + (number == len(timed) - 1)
            s, sd, sdd = sample_profile(item.profile, np.arange(steps) * (1 / rate))
            q, qd, qdd = joint_motion(item.stroke, s, sd, sdd)
            parts.append((q, qd, qdd, planned_points(item.stroke, s)))
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
    """`_significant_points_all` of one part, straightforwardly: every point's distance from
    the last one kept."""
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
    """`_corner_indexes_all` of one part as a loop over every point (the same directions)."""
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


def _every_few_one_by_one(points: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """`_every_few_all` of one part, from its own arc parameter: the bins' first points and
    both ends, sorted and distinct."""
    from keymps.motion.strokes import CARRY_SPACING_M, _parameter_steps

    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(_parameter_steps(points, yaw), axis=1))])
    bins = np.floor(arc / CARRY_SPACING_M)
    keep = np.flatnonzero(np.diff(bins, prepend=-1.0) > 0)
    return distinct(np.concatenate([keep, [0, len(points) - 1]]))


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
    from keymps.motion.strokes import _dense_points, _dense_points_all, _every_few_all

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
            want = _every_few_one_by_one(points, yaw)
            assert got.dtype == want.dtype and np.array_equal(got, want)


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

    from keymps.motion.timing import Limits, sample_trajectory, time_strokes_at_once

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
