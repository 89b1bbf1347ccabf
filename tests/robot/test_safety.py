"""The independent validator: accepts a planned trajectory, rejects hand-made bad ones."""

from __future__ import annotations

import math
from dataclasses import replace
from functools import cache
from typing import Any

import numpy as np
import pytest
from helpers.robot_toolpaths import assemble, polyline, ring_of_dots

from keymps.config.task import Task
from keymps.motion.timing import time_trajectory
from keymps.plugin import require_validated
from keymps.robot.model import RobotModel, solve_path
from keymps.robot.safety import SafetyError, validate
from keymps.types import ToolPath, Trajectory, ValidatedTrajectory, ValidationReport


def make_task(**robot: Any) -> Task:
    return Task.model_validate(
        {
            "name": "t",
            "instruction": "icing",
            "scene": {"image": "x.png", "object_height": 0.06},
            "primitives": ["line"],
            "robot": {"tool": "piping_bag", **robot},
        }
    )


def circle(radius: float, center: tuple[float, float] = (0.15, 0.09)) -> np.ndarray:
    angles = np.linspace(0, 2 * math.pi, 64, endpoint=False)
    return np.column_stack(
        [center[0] + radius * np.cos(angles), center[1] + radius * np.sin(angles)]
    )


CAKE = circle(0.06)


@cache
def planned() -> tuple[RobotModel, Trajectory, ToolPath, Task]:
    task = make_task()
    model = RobotModel.from_task(task)
    path = ring_of_dots(count=3)
    return model, time_trajectory(model, path, solve_path(model, path), task), path, task


def problems_of(trajectory: Trajectory, path: ToolPath | None = None, outline: Any = CAKE) -> str:
    model, _, planned_path, task = planned()
    with pytest.raises(SafetyError) as caught:
        validate(model, trajectory, path or planned_path, outline, task)
    message = str(caught.value)
    assert "\n" not in message and message.startswith("safety: ")
    return message


def test_a_planned_trajectory_passes_with_its_figures() -> None:
    model, trajectory, path, task = planned()
    validated = validate(model, trajectory, path, CAKE, task)
    assert isinstance(validated, ValidatedTrajectory) and validated.report.ok
    figures = validated.report.figures
    assert figures["max_deviation_from_tool_path_mm"] < 0.5
    assert figures["min_tool_z_mm"] > 60
    assert figures["max_joint_velocity_ratio"] <= 1.0 + 1e-3
    assert figures["max_work_outside_footprint_mm"] == 0.0
    assert require_validated(validated, "test") is validated.trajectory
    with pytest.raises(ValueError):
        validated.trajectory.q[0, 0] = 1.0  # read-only: cannot be edited after the check


def test_a_tool_going_below_the_board_is_rejected() -> None:
    model, _, _, task = planned()
    start = np.array([0.15, 0.09, 0.02])
    points = polyline([start, start + [0.02, 0, -0.03]], 0.001)
    path = assemble([(points, np.zeros(len(points)))], 0.09, "line", 0.02)
    trajectory = time_trajectory(model, path, solve_path(model, path), task)
    message = problems_of(trajectory, path)
    assert "mm below the board surface" in message
    assert "10.0 mm below" in message


def test_a_joint_jump_is_rejected() -> None:
    _, trajectory, _, _ = planned()
    q = trajectory.q.copy()
    q[200:, 0] += 0.2
    message = problems_of(replace(trajectory, q=q))
    assert "shoulder_pan_joint jumps by 0.200 rad" in message
    assert "leaves the tool path" in message


def test_a_velocity_spike_is_rejected_even_when_the_tool_stays_on_its_path() -> None:
    model, trajectory, _, _ = planned()
    period = 1.0 / trajectory.rate_hz
    # spin the piping bag about its own axis (the tip does not move) at 1.2x the wrist limit
    speed = np.zeros(len(trajectory.t))
    speed[100:130] = 1.2 * model.velocity_limits[5] * np.sin(np.linspace(0, math.pi, 30)) ** 2
    q = trajectory.q.copy()
    q[:, 5] += np.cumsum(speed) * period
    message = problems_of(replace(trajectory, q=q))
    assert "wrist_3_joint velocity" in message and "exceeds its limit 6.28 rad/s" in message
    assert "leaves" not in message and "jumps" not in message


def test_work_outside_the_object_footprint_is_rejected() -> None:
    _, trajectory, _, _ = planned()
    message = problems_of(trajectory, outline=circle(0.02))
    assert "work leaves the object's footprint by" in message


def test_a_trajectory_not_at_rest_or_off_the_controller_clock_is_rejected() -> None:
    _, trajectory, _, _ = planned()
    qd = trajectory.qd.copy()
    qd[0, 2] = 0.1
    assert "not at rest at the start" in problems_of(replace(trajectory, qd=qd))
    t = trajectory.t.copy()
    t[10:] += 0.003
    assert "samples are not 8.000 ms apart" in problems_of(replace(trajectory, t=t))


def test_executors_refuse_forged_or_modified_validated_trajectories() -> None:
    model, trajectory, path, task = planned()
    forged = ValidatedTrajectory(trajectory, ValidationReport(True, (), {}))
    with pytest.raises(SafetyError, match="did not come from keymps.robot.safety.validate"):
        require_validated(forged, "sim")
    with pytest.raises(SafetyError, match="did not come from"):
        require_validated(trajectory, "sim")
    validated = validate(model, trajectory, path, CAKE, task)
    q = trajectory.q.copy()
    q[50:, 0] += 0.5
    object.__setattr__(validated, "trajectory", replace(validated.trajectory, q=q))
    with pytest.raises(SafetyError, match="modified afterwards"):
        require_validated(validated, "sim")
    validated = validate(model, trajectory, path, CAKE, task)
    assert require_validated(validated, "sim") is validated.trajectory
    kind = np.array(validated.trajectory.kind, copy=True)
    kind[len(kind) // 2] = "travel" if kind[len(kind) // 2] == "work" else "work"
    object.__setattr__(validated, "trajectory", replace(validated.trajectory, kind=kind))
    with pytest.raises(SafetyError, match="modified afterwards"):
        require_validated(validated, "sim")


def test_distance_to_polyline_is_exact_on_large_inputs() -> None:
    from keymps.robot.safety_geometry import distance_to_polyline

    rng = np.random.default_rng(3)
    s = np.linspace(0, 4 * math.pi, 2500)
    spiral = np.column_stack([0.05 * np.cos(s) * s / 10, 0.05 * np.sin(s) * s / 10, s / 100])
    spiral = np.vstack([spiral, [[0.2, 0.2, 0.2]]])  # one long last segment
    points = rng.uniform(-0.06, 0.2, (400, 3))
    points = np.vstack([points, spiral[::7] + rng.normal(0, 2e-4, (358, 3))])
    a, b = spiral[:-1], spiral[1:]
    t = np.clip(((points[:, None] - a) * (b - a)).sum(-1) / ((b - a) ** 2).sum(-1), 0, 1)
    expected = np.linalg.norm(points[:, None] - (a + t[..., None] * (b - a)), axis=2).min(axis=1)
    assert np.allclose(distance_to_polyline(points, spiral), expected, atol=1e-12)
