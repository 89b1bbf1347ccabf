"""The sim and file executors: replay, outcome.png, exported files, refusal of unvalidated input."""

from __future__ import annotations

import json
import math
from functools import cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from robot_toolpaths import radial_cuts, ring_of_dots

from keymps.errors import KeympsError
from keymps.geometry import ImageFrame
from keymps.plugins import create_component
from keymps.robot import RobotModel, solve_path
from keymps.run import Run
from keymps.safety import SafetyError, validate
from keymps.stages import SceneImage, ToolPath, ValidatedTrajectory, ValidationReport
from keymps.task import Task
from keymps.timing import time_trajectory
from keymps.trajectory_io import CSV_HEADER, read_trajectory_csv

CENTER = (0.15, 0.09)


def make_task(tool: str, height: float) -> Task:
    return Task.model_validate(
        {
            "name": "t",
            "instruction": "do it",
            "scene": {"image": "x.png", "object_height": height},
            "primitives": ["line"],
            "robot": {"tool": tool},
        }
    )


def scene_image(radius_m: float) -> SceneImage:
    """A 600 x 360 board (2 px per mm) with a round beige object."""
    image = np.full((360, 600, 3), (90, 120, 90), np.uint8)
    cv2.circle(image, (300, 180), round(radius_m * 2000), (150, 200, 230), -1)
    return SceneImage(image, "test")


def outline(radius: float) -> np.ndarray:
    a = np.linspace(0, 2 * math.pi, 72, endpoint=False)
    return np.column_stack([CENTER[0] + radius * np.cos(a), CENTER[1] + radius * np.sin(a)])


@cache
def planned(kind: str) -> tuple[Task, ToolPath, Any]:
    if kind == "icing":
        task, path, radius = make_task("piping_bag", 0.06), ring_of_dots(count=6), 0.06
    else:
        task, path, radius = make_task("knife", 0.02), radial_cuts(count=4, top=0.025), 0.09
    model = RobotModel.from_task(task)
    trajectory = time_trajectory(model, path, solve_path(model, path), task)
    return task, path, (model, trajectory, radius)


def validated_run(kind: str, folder: Path) -> tuple[ValidatedTrajectory, Run]:
    task, path, (model, trajectory, radius) = planned(kind)
    run = Run(task=task, folder=folder)
    run.results["image"] = scene_image(radius)
    run.results["compose"] = path
    return validate(model, trajectory, path, outline(radius), task), run


def to_pixel(task: Task, xy: tuple[float, float]) -> tuple[int, int]:
    px = ImageFrame.from_task(task, (600, 360)).to_pixels(np.array([xy]))[0]
    return round(px[0]), round(px[1])


def is_cut(bgr: np.ndarray) -> bool:
    return bool(bgr.max() < 60)


def test_sim_draws_cuts_where_the_knife_went_through_the_food(tmp_path: Path) -> None:
    validated, run = validated_run("cutting", tmp_path)
    report = create_component("executor", "sim", {}).execute(validated, run)
    assert report.ok, report.message
    assert report.figures["cuts"] == 4
    assert report.figures["max_tracking_error_mm"] < 0.5
    assert report.figures["min_tool_z_mm"] > -0.5
    outcome = cv2.imread(str(tmp_path / "outcome.png"))
    assert outcome.shape == (360, 600, 3)
    for i in range(4):
        angle = 2 * math.pi * i / 4
        # the knife is below the pizza's top (2 cm) from about 1/5 of the way along each cut
        x, y = to_pixel(
            run.task, (CENTER[0] + 0.05 * math.cos(angle), CENTER[1] + 0.05 * math.sin(angle))
        )
        assert is_cut(outcome[y, x]), (i, outcome[y, x])
    # between the cuts nothing happened
    x, y = to_pixel(
        run.task,
        (CENTER[0] + 0.05 * math.cos(math.pi / 4), CENTER[1] + 0.05 * math.sin(math.pi / 4)),
    )
    assert not is_cut(outcome[y, x])
    assert np.array_equal(outcome[5, 5], run.results["image"].image[5, 5])


def test_sim_draws_icing_dots_on_the_cake(tmp_path: Path) -> None:
    validated, run = validated_run("icing", tmp_path)
    report = create_component("executor", "sim", {}).execute(validated, run)
    assert report.ok, report.message
    assert report.figures["icing_dots"] == 6 and report.figures["cuts"] == 0
    outcome = cv2.imread(str(tmp_path / "outcome.png"))
    for i in range(6):
        angle = 2 * math.pi * i / 6
        # ring_of_dots draws a 2 mm rosette left of each ring point: its centre is 2 mm to -x
        xy = (CENTER[0] + 0.045 * math.cos(angle) - 0.002, CENTER[1] + 0.045 * math.sin(angle))
        x, y = to_pixel(run.task, xy)
        assert outcome[y, x].min() > 230, (i, outcome[y, x])
    x, y = to_pixel(run.task, CENTER)
    assert outcome[y, x].min() < 200  # the middle of the cake stays bare


def test_file_executor_writes_csv_and_ros_joint_trajectory(tmp_path: Path) -> None:
    validated, run = validated_run("icing", tmp_path)
    elsewhere = tmp_path / "exports" / "plan.json"
    report = create_component("executor", "file", {"json": str(elsewhere)}).execute(validated, run)
    assert report.ok
    assert report.files == (str(tmp_path / "trajectory.csv"), str(elsewhere))
    trajectory = validated.trajectory
    lines = (tmp_path / "trajectory.csv").read_text().splitlines()
    assert lines[0] == CSV_HEADER == "t,q1,q2,q3,q4,q5,q6,x,y,z,piece,kind"
    assert len(lines) == trajectory.samples + 1
    table = read_trajectory_csv(tmp_path / "trajectory.csv")
    assert np.allclose(table["t"], trajectory.t, atol=1e-6)
    assert np.allclose(table["q"], trajectory.q, atol=1e-9)
    assert np.allclose(table["xyz"], trajectory.tool_xyz, atol=1e-6)
    assert np.array_equal(table["piece"], trajectory.piece_index)
    assert list(table["kind"]) == list(trajectory.kind)
    message = json.loads(elsewhere.read_text())
    assert message["joint_names"] == list(trajectory.joint_names)
    points = message["points"]
    assert len(points) == trajectory.samples
    for i in (0, 17, trajectory.samples - 1):
        stamp = points[i]["time_from_start"]
        assert 0 <= stamp["nanosec"] < 1_000_000_000
        assert stamp["sec"] + stamp["nanosec"] * 1e-9 == pytest.approx(trajectory.t[i], abs=1e-9)
        assert points[i]["positions"] == pytest.approx(list(trajectory.q[i]))
        assert points[i]["velocities"] == pytest.approx(list(trajectory.qd[i]))
        assert points[i]["accelerations"] == pytest.approx(list(trajectory.qdd[i]))


def test_file_executor_skips_a_null_file_and_rejects_unknown_options(tmp_path: Path) -> None:
    validated, run = validated_run("icing", tmp_path)
    report = create_component("executor", "file", {"csv": None}).execute(validated, run)
    assert report.files == (str(tmp_path / "trajectory.json"),)
    assert not (tmp_path / "trajectory.csv").exists()
    with pytest.raises(KeympsError, match="executor file: jsn: unknown option"):
        create_component("executor", "file", {"jsn": "x.json"})
    with pytest.raises(KeympsError, match="executor sim: replay_rate_hz"):
        create_component("executor", "sim", {"replay_rate_hz": 0})


@pytest.mark.parametrize("name", ["sim", "file"])
def test_executors_refuse_anything_not_validated(name: str, tmp_path: Path) -> None:
    validated, run = validated_run("icing", tmp_path)
    executor = create_component("executor", name, {})
    forged = ValidatedTrajectory(validated.trajectory, ValidationReport(True, (), {}))
    for candidate in (forged, validated.trajectory):
        with pytest.raises(SafetyError, match=f"executor '{name}' refuses"):
            executor.execute(candidate, run)
    assert not any(tmp_path.iterdir())


def test_marks_tell_cuts_from_icing_and_find_contact_below_the_board() -> None:
    from keymps.default_plugins.sim_executor import Replay, marks

    line = np.linspace([0.1, 0.1, 0.03], [0.2, 0.1, -0.002], 101)  # a cut ending 2 mm too deep
    dot = np.tile([0.05, 0.05, 0.065], (30, 1))
    stroke = np.linspace([0.05, 0.12, 0.065], [0.09, 0.12, 0.065], 41)
    xyz = np.concatenate([line, dot, stroke])
    piece = np.repeat([1, 3, 5], [101, 30, 41])
    found = marks(Replay(np.arange(len(xyz)) * 1e-3, xyz, xyz, piece, np.full(172, "work")), 0.02)
    assert len(found.cuts) == 1 and len(found.dots) == 1 and len(found.strokes) == 1
    # the cut starts where the knife enters the food (z < 2 cm), not where the piece starts
    assert found.cuts[0][0, 0] == pytest.approx(0.1 + 0.1 * (0.01 / 0.032), abs=0.002)
    assert np.allclose(found.dots[0], [0.05, 0.05])
    assert len(found.contacts) == 5  # z = 0.03 - 0.032 k / 100 < -0.5 mm for k = 96..100
