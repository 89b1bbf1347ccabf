"""Ruckig timing: limits on a 1 kHz resampling, rests at corners and pieces, tool speeds."""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import numpy as np
import pytest
from helpers.robot_toolpaths import HOME, assemble, polyline, radial_cuts, ring_of_dots

from keymps.config.task import Task
from keymps.motion.timing import time_trajectory
from keymps.robot.model import RobotModel, solve_path
from keymps.types import Piece, ToolPath, Trajectory


def make_task(**robot: Any) -> Task:
    return Task.model_validate(
        {
            "name": "t",
            "instruction": "cut it",
            "scene": {"image": "x.png", "object_height": 0.06},
            "primitives": ["straight"],
            "robot": robot,
        }
    )


def plan(path: ToolPath, **robot: Any) -> tuple[RobotModel, Trajectory]:
    task = make_task(**robot)
    model = RobotModel.from_task(task)
    return model, time_trajectory(model, path, solve_path(model, path), task)


@cache
def cuts_at_1khz() -> tuple[RobotModel, Trajectory, ToolPath]:
    path = radial_cuts(count=3)
    model, trajectory = plan(path, tool="knife", rate_hz=1000)
    return model, trajectory, path


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    length2 = np.maximum((ab**2).sum(axis=1), 1e-18)
    t = np.clip(((points[:, None, :] - a[None]) * ab[None]).sum(axis=2) / length2, 0, 1)
    nearest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - nearest, axis=2).min(axis=1)


def test_every_joint_limit_holds_on_a_1khz_sampling() -> None:
    model, trajectory, _ = cuts_at_1khz()
    period = 1.0 / 1000
    assert trajectory.rate_hz == 1000
    assert np.allclose(np.diff(trajectory.t), period)
    # measured from the positions alone, as a controller would see them
    velocity = np.diff(trajectory.q, axis=0) / period
    acceleration = np.diff(velocity, axis=0) / period
    jerk = np.diff(acceleration, axis=0) / period
    assert np.all(np.abs(velocity) <= model.velocity_limits * 1.001)
    assert np.all(np.abs(acceleration) <= model.acceleration_limits * 1.01)
    assert np.all(np.abs(jerk) <= model.jerk_limits * 1.02)
    # the reported derivatives agree with the positions
    assert np.abs(velocity - (trajectory.qd[1:] + trajectory.qd[:-1]) / 2).max() < 1e-3
    assert np.all(np.abs(trajectory.qd) <= model.velocity_limits)
    assert np.all(np.abs(trajectory.qdd) <= model.acceleration_limits * 1.001)
    assert np.all(trajectory.q >= model.lower) and np.all(trajectory.q <= model.upper)


def test_joints_follow_the_planned_tool_path_within_a_tenth_of_a_millimetre() -> None:
    model, trajectory, path = cuts_at_1khz()
    reached = model.tool_positions(trajectory.q[::5])
    assert np.linalg.norm(reached - trajectory.tool_xyz[::5], axis=1).max() < 1e-4
    for index, piece in enumerate(path.pieces):
        mine = trajectory.piece_index[::5] == index
        assert distance_to_polyline(reached[mine], piece.points).max() < 1e-4


def test_fields_rests_and_order_of_pieces() -> None:
    path = ring_of_dots(count=4)
    model, trajectory = plan(path, tool="piping_bag")
    n = trajectory.samples
    assert trajectory.rate_hz == 125
    assert trajectory.q.shape == trajectory.qd.shape == trajectory.qdd.shape == (n, 6)
    assert trajectory.tool_xyz.shape == (n, 3)
    assert trajectory.joint_names == model.joint_names
    assert np.allclose(trajectory.tool_xyz[0], HOME) and np.allclose(trajectory.tool_xyz[-1], HOME)
    assert np.all(np.diff(trajectory.piece_index) >= 0)
    assert set(trajectory.piece_index) == set(range(len(path.pieces)))
    kinds = np.array([path.pieces[i].kind for i in trajectory.piece_index])
    assert np.array_equal(trajectory.kind, kinds)
    # at rest where one piece hands over to the next, at the start and at the end
    changes = np.flatnonzero(np.diff(trajectory.piece_index)) + 1
    for i in [0, n - 1, *changes]:
        assert np.abs(trajectory.qd[i]).max() < 1e-9
        assert np.abs(trajectory.qdd[i]).max() < 1e-6


def test_work_runs_at_the_requested_tool_speed_and_stops_at_sharp_corners() -> None:
    start = np.array([0.08, 0.05, 0.065])
    corner = start + [0.12, 0.0, 0.0]
    end = corner + [0.0, 0.08, 0.0]
    points = polyline([start, corner, end], 0.001)
    path = assemble([(points, np.zeros(len(points)))], 0.095, "line", 0.04)
    _, trajectory = plan(path, tool="piping_bag")
    work = trajectory.kind == "work"
    speed = np.linalg.norm(np.diff(trajectory.tool_xyz, axis=0), axis=1) * trajectory.rate_hz
    work_speed = speed[work[1:] & work[:-1]]
    assert work_speed.max() == pytest.approx(0.04, rel=0.02)
    at_corner = np.linalg.norm(trajectory.tool_xyz - corner, axis=1) < 1e-9
    assert at_corner.any()
    assert np.abs(trajectory.qd[at_corner]).max() < 1e-9
    # travel may be faster than work, never faster than asked
    assert speed.max() <= 0.15 * 1.01


def test_a_lower_joint_acceleration_limit_slows_the_trajectory_down() -> None:
    path = radial_cuts(count=2)
    model_fast, fast = plan(path, tool="knife")
    model_slow, slow = plan(path, tool="knife", max_joint_acceleration=0.4)
    assert np.abs(fast.qdd).max() > 0.4
    assert np.abs(slow.qdd).max() <= 0.4 * 1.001
    assert slow.duration_s > fast.duration_s * 1.05


def test_e_series_defaults_to_500_hz_and_a_task_rate_wins() -> None:
    points = polyline([HOME, HOME + [0.05, 0, 0]], 0.005)
    path = ToolPath((Piece("travel", 0, points, np.zeros(len(points)), 0.1),), "line")
    assert plan(path, model="ur3e")[1].rate_hz == 500
    assert plan(path, model="ur3", rate_hz=250)[1].rate_hz == 250


def test_a_dwell_that_jitters_by_micrometres_is_one_reversal_not_a_slow_crawl() -> None:
    # an icing dot: down 4 mm, a dwell with 1 um noise, back up (what a DMP rollout gives)
    rng = np.random.default_rng(0)
    top = np.array([0.15, 0.09, 0.065])
    down = top - np.linspace(0, 0.004, 12)[:, None] * [0, 0, 1]
    dwell = top - [0, 0, 0.004] + rng.normal(0, 1e-6, (25, 3))
    points = np.vstack([down, dwell, down[::-1]])
    path = assemble([(points, np.zeros(len(points)))], 0.095, "line", 0.03)
    model, trajectory = plan(path, tool="piping_bag")
    work = trajectory.kind == "work"
    # two rest-to-rest strokes of 4 mm: a fraction of a second, not seconds of crawling
    assert 0.2 < work.sum() / trajectory.rate_hz < 1.0
    bottom = np.argmin(np.where(work, trajectory.tool_xyz[:, 2], np.inf))
    assert trajectory.tool_xyz[bottom, 2] == pytest.approx(0.061, abs=2e-5)
    assert np.abs(trajectory.qd[bottom]).max() < 1e-9


def test_a_work_piece_that_never_moves_is_skipped_not_a_crash() -> None:
    # a dot with all DMP weights zero (the vlm-keypoint ablation): start = goal, no motion
    still = np.repeat([[0.15, 0.09, 0.065]], 20, axis=0)
    path = assemble([(still, np.zeros(len(still)))], 0.095, "line", 0.03)
    model, trajectory = plan(path, tool="piping_bag")
    assert trajectory.duration_s > 0
    assert not (trajectory.kind == "work").any()
    reached = np.linalg.norm(trajectory.tool_xyz - still[0], axis=1).min()
    assert reached < 1e-6  # the travel move still brings the nozzle to the dot


def test_of_two_corner_points_equally_near_the_middle_the_first_is_the_corner() -> None:
    """Their distances to the middle differ only in the last bit of a sum, which differs
    between CPUs (NumPy's AVX-512 and AVX2 loops): the choice must not follow that bit."""
    from keymps.motion.strokes import _nearest_first

    rng = np.random.default_rng(7)
    for _ in range(200):
        a = float(rng.uniform(0.0, 0.2))
        b = a + float(rng.uniform(2e-4, 4e-4))
        middle = (a + b) / 2
        for nudge in (-2, -1, 0, 1, 2):
            shifted = float(np.nextafter(middle, np.inf if nudge > 0 else -np.inf))
            shifted = middle if nudge == 0 else shifted
            assert _nearest_first([a, b], 0, 1, shifted) == 0
    assert _nearest_first([0.0, 1e-4, 3e-4], 0, 2, 2.9e-4) == 2  # a clear nearest still wins


def test_where_a_stroke_ends_at_a_corner_does_not_follow_the_last_bit_of_rounding() -> None:
    """Sharp Vs sampled unevenly: perturbing every coordinate by a few units in the last place
    (what another CPU's rounding does) never moves a corner to another point. (With the
    nearest point to the middle chosen by the bare minimum, most of these paths move it.)"""
    from keymps.motion.strokes import _corner_indexes_all

    rng = np.random.default_rng(3)
    step = 2.5e-4
    for _ in range(100):
        x = (np.arange(-40, 40) + 0.5) * step + rng.uniform(-2e-5, 2e-5, 80)
        points = np.column_stack([0.1 + x, 0.054 - np.abs(x), np.full(len(x), 0.06)])
        yaw = np.zeros(len(points))
        corners = _corner_indexes_all([(points, yaw)])[0]
        assert len(corners) == 1 and abs(corners[0] - 39.5) < 3  # at the tip
        for _ in range(10):
            ulps = rng.integers(-4, 5, size=points.shape)
            turned = points + ulps * np.spacing(points)
            assert _corner_indexes_all([(turned, yaw)])[0] == corners


def test_a_spiral_piped_as_one_stroke_does_not_stop_at_its_48_joints() -> None:
    """Consecutive spiral segments turn by about 20 degrees, less than the corner angle: the
    tool runs through every joint at the work speed and rests only where the nozzle goes down
    and comes up (three timing strokes for 48 pairs), inside every joint limit."""
    from keymps.designs.patterns import spiral
    from keymps.motion.compose import compose_tool_path
    from keymps.motion.strokes import split_strokes
    from keymps.primitives.dictionary import BUNDLED_DIR, load_primitives
    from keymps.robot.safety import validate
    from keymps.types import Segment

    z = 0.065
    segments = [
        Segment(np.array([*a, z]), np.array([*b, z]), (0, 0), (0, 0))
        for a, b in spiral((0.15, 0.09), 0.002, 0.035, 3.0, 48)
    ]
    line = load_primitives(["line"], [BUNDLED_DIR])["line"]
    task = make_task(tool="piping_bag")
    model = RobotModel.from_task(task)
    path = compose_tool_path(
        segments, line, object_top=0.06, clearance=0.03, work_speed=0.03, travel_speed=0.15,
        yaw_mode="fixed", home=model.home_tool_position(), join_distance=0.002,
    )  # fmt: skip
    joints = solve_path(model, path)
    assert [s.piece_index for s in split_strokes(model, path, joints)].count(1) == 3
    trajectory = time_trajectory(model, path, joints, task)
    cake = 0.15 + 0.06 * np.column_stack(
        [np.cos(np.arange(72) / 72 * 2 * np.pi), np.sin(np.arange(72) / 72 * 2 * np.pi)]
    )
    cake[:, 1] -= 0.06
    validate(model, trajectory, path, cake, task)  # raises on any broken limit
    on_spiral = (trajectory.piece_index == 1) & (trajectory.tool_xyz[:, 2] < z - 0.0039)
    speed = np.linalg.norm(np.diff(trajectory.tool_xyz, axis=0), axis=1) * trajectory.rate_hz
    moving = speed[on_spiral[1:] & on_spiral[:-1]]
    assert moving.max() <= 0.03 * 1.01
    assert np.mean(moving > 0.029) > 0.9  # at the work speed, not stopping at each joint
    rests = (moving[1:-1] < 1e-4) & (moving[1:-1] <= moving[:-2]) & (moving[1:-1] <= moving[2:])
    assert rests.sum() <= 2  # where it reaches the drawing height and where it leaves it


@pytest.mark.parametrize(
    ("acceleration", "jerk", "ruckig_says"),
    [
        (0.0, 20.0, "zero limits conflict"),
        (2.0, -1.0, "maximum jerk limit -1"),
        (math.nan, 20.0, "maximum acceleration limit nan"),
    ],
)
def test_strokes_ruckig_cannot_time_say_which_and_why_in_one_line(
    acceleration: float, jerk: float, ruckig_says: str
) -> None:
    """Every stroke fails in Ruckig: each keeps Ruckig's own reason, named with its piece and
    the limits it was asked for (not the joint-limit message of a stroke that stays too fast)."""
    from keymps.errors import KeympsError
    from keymps.motion.strokes import split_strokes
    from keymps.motion.timing import Limits, time_strokes_at_once

    path = radial_cuts(count=2)
    model = RobotModel.from_task(make_task(tool="knife"))
    strokes = split_strokes(model, path, solve_path(model, path))
    timed = time_strokes_at_once(model, strokes, Limits(math.inf, acceleration, jerk), 1 / 500)
    assert len(timed) == len(strokes) >= 4
    for stroke, error in zip(strokes, timed, strict=True):
        assert isinstance(error, KeympsError)
        line = str(error)
        assert "\n" not in line and "singularity" not in line, line
        assert line.startswith(
            f"timing: Ruckig could not time a {stroke.length:.4f} m stroke of piece "
            f"{stroke.piece_index} ({stroke.kind}) at velocity {stroke.speed:.4g} m/s, "
            f"acceleration {acceleration:.4g} m/s^2, jerk {jerk:.4g} m/s^3: "
        ), line
        assert ruckig_says in line, line
