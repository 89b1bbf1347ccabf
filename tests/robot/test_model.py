"""UR3 kinematics: the URDF against the DH table, IK accuracy, one configuration, reach errors."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from helpers.robot_toolpaths import radial_cuts, ring_of_dots

from keymps.config.task import Task
from keymps.errors import KeympsError
from keymps.robot.model import (
    ARMS,
    BUILTIN_TOOLS,
    RobotModel,
    Tool,
    solve_path,
    tool_from_task,
    tool_rotation,
)
from keymps.run import RunOptions, RunOverrides
from keymps.types import Piece, ToolPath


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


def dh_flange(q: np.ndarray, kind: str) -> np.ndarray:
    """The flange pose from the maker's standard DH table (independent of Pinocchio)."""
    arm = ARMS[kind]
    d = [arm.d1, 0, 0, arm.d4, arm.d5, arm.d6]
    a = [0, -arm.upper_arm, -arm.forearm, 0, 0, 0]
    alpha = [math.pi / 2, 0, 0, math.pi / 2, -math.pi / 2, 0]
    pose = np.eye(4)
    for i in range(6):
        ct, st = math.cos(q[i]), math.sin(q[i])
        ca, sa = math.cos(alpha[i]), math.sin(alpha[i])
        pose = pose @ np.array(
            [
                [ct, -st * ca, st * sa, a[i] * ct],
                [st, ct * ca, -ct * sa, a[i] * st],
                [0, sa, ca, d[i]],
                [0, 0, 0, 1],
            ]
        )
    return pose


@pytest.mark.parametrize("kind", ["ur3", "ur3e"])
def test_urdf_model_matches_the_dh_table(kind: str) -> None:
    # base yaw 180: robot.base places the URDF base_link; the DH base frame is turned by pi.
    model = RobotModel(kind, (0.0, 0.0, 0.0, 180.0), Tool("flange", (0.0, 0.0, 0.0), "fixed"))
    rng = np.random.default_rng(1)
    for q in rng.uniform(-math.pi, math.pi, (20, 6)):
        position, rotation = model.fk(q)
        expected = dh_flange(q, kind)
        assert np.allclose(position, expected[:3, 3], atol=1e-9)
        assert np.allclose(rotation, expected[:3, :3], atol=1e-9)


def test_base_placement_and_tcp_offset_move_the_tool_tip() -> None:
    q = np.array([0.3, -1.2, 1.4, -1.8, -1.57, 0.4])
    at_origin = RobotModel("ur3", (0, 0, 0, 0), Tool("t", (0, 0, 0.1), "fixed"))
    moved = RobotModel("ur3", (0.1, -0.2, 0.05, 90), Tool("t", (0, 0, 0.1), "fixed"))
    p0, r0 = at_origin.fk(q)
    p1, r1 = moved.fk(q)
    turn = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
    assert np.allclose(p1, turn @ p0 + [0.1, -0.2, 0.05], atol=1e-12)
    assert np.allclose(r1, turn @ r0, atol=1e-12)
    flange = RobotModel("ur3", (0, 0, 0, 0), Tool("t", (0, 0, 0), "fixed"))
    pf, rf = flange.fk(q)
    assert np.allclose(p0, pf + rf @ [0, 0, 0.1], atol=1e-12)


def test_ik_reaches_tool_down_poses_over_the_board_within_tolerance() -> None:
    model = RobotModel.from_task(make_task())
    rng = np.random.default_rng(2)
    home = model.home_tool_position()
    seed = model.tool_down_seed(home, 0.0)
    for _ in range(30):
        target = rng.uniform([0.0, 0.0, 0.0], [0.30, 0.18, 0.12])
        yaw = float(rng.uniform(-math.pi, math.pi))
        result = model.ik(target, yaw, seed)
        assert result.converged
        position, rotation = model.fk(result.q)
        assert np.linalg.norm(position - target) < 1e-4
        assert rotation[2, 2] == pytest.approx(-1.0, abs=1e-6)  # pointing straight down
        assert np.allclose(rotation, tool_rotation(yaw), atol=1e-5)
        assert model.configuration_problem(result.q) is None


def elbow_above_line(model: RobotModel, q: np.ndarray) -> bool:
    """Elbow up: the elbow lies above the line from the shoulder to the wrist."""
    origins = model.joint_origins(q)
    shoulder, elbow, wrist = origins[1], origins[2], origins[3]
    along = np.dot(elbow[:2] - shoulder[:2], wrist[:2] - shoulder[:2])
    horizontal = np.linalg.norm(wrist[:2] - shoulder[:2]) or 1.0
    fraction = np.clip(along / horizontal**2, 0, 1)
    line_z = shoulder[2] + fraction * (wrist[2] - shoulder[2])
    return bool(elbow[2] > line_z)


@pytest.mark.parametrize(
    ("tool", "path"), [("piping_bag", ring_of_dots()), ("knife", radial_cuts())]
)
def test_solved_path_tracks_every_point_in_one_configuration(tool: str, path: Any) -> None:
    model = RobotModel.from_task(make_task(tool=tool))
    joint_path = solve_path(model, path)
    assert joint_path.max_position_error_m < 1e-4
    assert joint_path.max_rotation_error_rad < math.radians(0.1)
    assert len(joint_path.pieces) == len(path.pieces)
    all_q = np.concatenate(joint_path.pieces)
    for piece, qs in zip(path.pieces, joint_path.pieces, strict=True):
        assert qs.shape == (len(piece.points), 6)
        positions, rotations = model.tool_poses(qs)
        assert np.abs(positions - piece.points).max() < 1e-4
        assert np.allclose(rotations[:, 2, 2], -1.0, atol=1e-6)
    # one configuration: elbow up, wrist on the same side, no jump between neighbours
    assert np.all(all_q[:, 2] > 0) and np.all(np.sin(all_q[:, 4]) < -0.2)
    assert all(elbow_above_line(model, q) for q in all_q[::25])
    # no jump: each joint step is in proportion to how far the tool moved and turned
    points = np.concatenate([p.points for p in path.pieces])
    yaws = np.concatenate([p.yaw for p in path.pieces])
    tool_step = 30 * np.linalg.norm(np.diff(points, axis=0), axis=1) + 1.5 * np.abs(np.diff(yaws))
    assert np.all(np.abs(np.diff(all_q, axis=0)).max(axis=1) <= tool_step + 1e-6)
    assert np.all(all_q >= model.lower) and np.all(all_q <= model.upper)


def test_out_of_reach_board_names_the_piece_the_distance_and_the_fix() -> None:
    model = RobotModel.from_task(make_task(base=[0.15, -0.60, 0.0, 90.0]))
    with pytest.raises(KeympsError) as caught:
        solve_path(model, ring_of_dots())
    message = str(caught.value)
    assert "path pieces are out of the UR3's reach" in message
    assert "robot.base, now [0.15, -0.6, 0, 90]" in message
    piece = int(message.split("; piece ")[1].split(" ")[0])
    assert 0 <= piece < len(ring_of_dots().pieces)
    amount_cm = float(message.split(") by ")[1].split(" cm")[0])
    # the far side of the ring is about 0.6 + 0.09 + 0.045 m from the base: well out of reach
    assert 10 < amount_cm < 40


def test_a_slightly_out_of_reach_board_reports_centimetres() -> None:
    model = RobotModel.from_task(make_task(base=[0.15, -0.45, 0.0, 90.0]))
    shortfall = model.reach_shortfall(np.array([[0.15, 0.18, 0.06]]))[0]
    assert 0 < shortfall < 0.2


def test_tools_builtin_custom_and_unknown() -> None:
    assert tool_from_task(make_task(tool="knife")) == BUILTIN_TOOLS["knife"]
    assert tool_from_task(make_task(tool="piping_bag")).yaw == "fixed"
    custom = tool_from_task(make_task(tool={"name": "spatula", "tcp": [0, 0.01, 0.2]}))
    assert custom.tcp == (0.0, 0.01, 0.2) and custom.yaw == "fixed"
    longer_knife = tool_from_task(make_task(tool={"name": "knife", "tcp": [0, 0, 0.14]}))
    assert longer_knife.tcp == (0, 0, 0.14) and longer_knife.yaw == "follow"
    with pytest.raises(KeympsError, match="unknown tool 'spoon'.*knife, piping_bag"):
        tool_from_task(make_task(tool="spoon"))


def test_home_is_above_the_middle_of_the_board_and_reachable() -> None:
    model = RobotModel.from_task(make_task())
    home = model.home_tool_position()
    assert home[:2] == pytest.approx([0.15, 0.09])
    assert home[2] > 0.06 + 0.03
    assert model.reach_shortfall(home[None])[0] < 0


def test_a_malformed_piece_is_a_clear_error() -> None:
    model = RobotModel.from_task(make_task())
    bad = Piece("work", 0, np.zeros((4, 3)) + [0.15, 0.09, 0.07], np.zeros(3), 0.03)
    with pytest.raises(KeympsError, match=r"piece 0 \(work\): yaw must have one value per point"):
        solve_path(model, ToolPath((bad,), "line"))


@pytest.mark.parametrize("task_file", ["cake_icing.yaml", "object_cutting.yaml"])
def test_shipped_tasks_solve_time_and_validate_within_every_bound(
    task_file: str, tmp_path: Any
) -> None:
    from pathlib import Path

    from keymps import load_task, run_task

    task = load_task(Path(__file__).resolve().parents[2] / "tasks" / task_file)
    run = run_task(
        task,
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(out=tmp_path, backend="offline", executor="file"),
    )
    model = RobotModel.from_task(task)
    tool_path, joint_path = run.stages.compose, run.stages.solve
    for piece, qs in zip(tool_path.pieces, joint_path.pieces, strict=True):
        positions, rotations = model.tool_poses(qs)
        assert np.linalg.norm(positions - piece.points, axis=1).max() < 1e-4
        yaw = np.arctan2(rotations[:, 1, 0], rotations[:, 0, 0])
        assert np.abs(np.angle(np.exp(1j * (yaw - piece.yaw)))).max() < math.radians(0.1)
        assert all(model.configuration_problem(q) is None for q in qs)
    trajectory = run.stages.time
    period = 1 / trajectory.rate_hz
    velocity = np.diff(trajectory.q, axis=0) / period
    assert np.all(np.abs(velocity) <= model.velocity_limits * 1.001)
    assert np.all(np.abs(np.diff(velocity, axis=0) / period) <= model.acceleration_limits * 1.01)
    figures = run.stages.check.report.figures
    assert figures["max_deviation_from_tool_path_mm"] < 0.5
    assert (tmp_path / "trajectory.json").is_file()
