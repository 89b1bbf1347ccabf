"""The sim and file executors: replay, outcome.png, exported files, refusal of unvalidated input."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from functools import cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from helpers.robot_toolpaths import radial_cuts, ring_of_dots

from keymps.config.task import Task
from keymps.errors import KeympsError
from keymps.motion.timing import time_trajectory
from keymps.motion.trajectory_io import CSV_HEADER, read_trajectory_csv
from keymps.perception.frames import ImageFrame
from keymps.plugin.manager import create_component
from keymps.robot.model import RobotModel, solve_path
from keymps.robot.safety import SafetyError, validate
from keymps.run import Run, RunOptions, RunOverrides
from keymps.types import SceneImage, ToolPath, ValidatedTrajectory, ValidationReport

CENTER = (0.15, 0.09)


def make_task(tool: str, height: float, base: list[float] | None = None) -> Task:
    robot: dict[str, Any] = {"tool": tool} if base is None else {"tool": tool, "base": base}
    return Task.model_validate(
        {
            "name": "t",
            "instruction": "do it",
            "scene": {"image": "x.png", "object_height": height},
            "primitives": ["line"],
            "robot": robot,
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
        # 5 cm further back than the UR3's default: the cut towards the base ends 5 mm from the
        # board's edge, where at the default place the elbow folds until the upper arm's and
        # wrist 1's collision meshes overlap (the safety check refuses that)
        knife = make_task("knife", 0.02, [0.15, -0.25, 0.0, 90.0])
        task, path, radius = knife, radial_cuts(count=4, top=0.025), 0.09
    model = RobotModel.from_task(task)
    trajectory = time_trajectory(model, path, solve_path(model, path), task)
    return task, path, (model, trajectory, radius)


def validated_run(kind: str, folder: Path) -> tuple[ValidatedTrajectory, Run]:
    task, path, (model, trajectory, radius) = planned(kind)
    run = Run(task=task, folder=folder)
    run.stages.image = scene_image(radius)
    run.stages.compose = path
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
    assert np.array_equal(outcome[5, 5], run.stages.image.image[5, 5])


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
    report = create_component("executor", "file", {"json": "exports/plan.json"}).execute(
        validated, run
    )
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


@pytest.mark.parametrize(
    "options",
    [
        {"csv": "/etc/cron.d/evil"},
        {"json": "../../../../tmp/escape.json"},
        {"csv": "exports/../../outside.csv"},
        {"json": "."},
    ],
)
def test_a_task_file_cannot_make_the_file_executor_write_outside_the_run_folder(
    tmp_path: Path, options: dict
) -> None:
    """A shared task file once wrote /etc/cron.d/evil as root (docs/security.md)."""
    key, value = next(iter(options.items()))
    with pytest.raises(KeympsError) as caught:
        create_component("executor", "file", options)
    assert str(caught.value) == (
        f"executor file: option {key!r}: {value!r} leads out of the run folder: name a file "
        "in it (--out chooses the folder) (options: csv, json)"
    )


def test_file_executor_writes_the_runs_csv_once_and_a_stale_one_again(tmp_path: Path) -> None:
    """Inside a pipeline run the engine has written trajectory.csv of this very trajectory just
    before the executor: it is kept, not written twice. Called on its own (run.stages.check is
    not this trajectory), the executor writes it whatever the folder holds."""
    validated, run = validated_run("icing", tmp_path)
    executor = create_component("executor", "file", {"json": None})
    stale = tmp_path / "trajectory.csv"
    stale.write_text("stale\n")
    assert executor.execute(validated, run).files == (str(stale),)
    fresh = stale.read_text()
    assert (
        fresh.startswith(CSV_HEADER) and len(fresh.splitlines()) == validated.trajectory.samples + 1
    )
    run.stages.check = validated  # as the engine records it before executing
    stale.write_text("written by the engine\n")
    assert executor.execute(validated, run).files == (str(stale),)
    assert stale.read_text() == "written by the engine\n"


def test_file_executor_skips_a_null_file_and_rejects_unknown_options(tmp_path: Path) -> None:
    validated, run = validated_run("icing", tmp_path)
    report = create_component("executor", "file", {"csv": None}).execute(validated, run)
    assert report.files == (str(tmp_path / "trajectory.json"),)
    assert not (tmp_path / "trajectory.csv").exists()
    with pytest.raises(KeympsError, match="executor file: option 'jsn': unknown option"):
        create_component("executor", "file", {"jsn": "x.json"})
    with pytest.raises(KeympsError, match="executor sim: option 'replay_rate_hz'"):
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
    from keymps.default_plugins.sim.executor import Replay, marks

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


REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def shipped_cutting(tmp_path_factory: pytest.TempPathFactory) -> Run:
    """tasks/object_cutting.yaml run end to end offline: 4 diameter cuts of the pizza."""
    from keymps.pipeline.engine import run_task

    folder = tmp_path_factory.mktemp("object_cutting")
    return run_task(
        REPO / "tasks/object_cutting.yaml",
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(out=folder, backend="offline"),
    )


def cut_coverage(outcome: np.ndarray, run: Run) -> list[float]:
    """Per grounded cut, the share of its line inside the pizza (2 mm in from the outline) that
    outcome.png shows cut, sampled every 0.5 mm."""
    from keymps.perception.frames import object_outline_m

    size = (outcome.shape[1], outcome.shape[0])
    pizza = object_outline_m(run.stages.detect, run.task, size).astype(np.float32)
    frame = ImageFrame.from_task(run.task, size)
    shares = []
    for segment in run.stages.ground.segments:
        start, goal = np.asarray(segment.start)[:2], np.asarray(segment.goal)[:2]
        count = int(np.linalg.norm(goal - start) / 0.0005) + 1
        line = start + np.linspace(0.0, 1.0, count)[:, None] * (goal - start)
        inside = [cv2.pointPolygonTest(pizza, (float(x), float(y)), True) > 0.002 for x, y in line]
        pixels = np.round(frame.to_pixels(line[inside])).astype(int)
        shares.append(float(np.mean([is_cut(outcome[y, x]) for x, y in pixels])))
    return shares


def test_a_knife_cuts_with_its_whole_blade_across_the_pizza(shipped_cutting: Run) -> None:
    run = shipped_cutting
    report = run.stages.execute
    assert report.ok, report.message
    assert report.figures["cuts"] == 4 and report.figures["blade_length_mm"] == 160
    outcome = cv2.imread(str(run.folder / "outcome.png"))
    coverage = cut_coverage(outcome, run)
    assert len(coverage) == 4 and min(coverage) >= 0.95, coverage
    # each cut goes through the whole pizza (300 px across at 0.5 mm per px: 150 mm)
    x0, _, x1, _ = run.stages.detect.bbox_px
    diameter_mm = (x1 - x0) * 0.5
    for k in range(4):
        assert report.figures[f"cut_{k + 1}_length_mm"] == pytest.approx(diameter_mm, abs=4)
    # the blade cuts only the food: the board around the pizza is untouched
    scene = run.stages.image.image
    x, y = to_pixel(run.task, (0.02, 0.09))  # left of the pizza, on the horizontal cut's line
    assert np.array_equal(outcome[y, x], scene[y, x])
    # between the cuts (halfway between two diameters, mid-radius) the pizza is whole
    centre = np.mean([np.asarray(s.goal)[:2] for s in run.stages.ground.segments], axis=0)
    between = centre + 0.04 * np.array([math.cos(math.pi / 8), math.sin(math.pi / 8)])
    x, y = to_pixel(run.task, (float(between[0]), float(between[1])))
    assert np.array_equal(outcome[y, x], scene[y, x])


def test_a_tiny_blade_cuts_only_where_the_tip_went_below_the_top(
    shipped_cutting: Run, tmp_path: Path
) -> None:
    from keymps.config.task import ToolSpec

    full = shipped_cutting
    robot = full.task.robot.model_copy(update={"tool": ToolSpec(name="knife", blade_length=0.001)})
    run = Run(task=full.task.model_copy(update={"robot": robot}), folder=tmp_path)
    run.stages = replace(full.stages, execute=None)
    report = create_component("executor", "sim", {}).execute(full.stages.check, run)
    assert report.ok, report.message
    assert report.figures["cuts"] == 4 and report.figures["blade_length_mm"] == 1
    coverage = cut_coverage(cv2.imread(str(tmp_path / "outcome.png")), run)
    # the tip descends from 5 mm above the top to the board along the line: it is in the
    # food over the last 4/5 of each cut only (Appendix C start-height grounding)
    assert all(0.6 < share < 0.9 for share in coverage), coverage
    for k in range(4):
        assert (
            report.figures[f"cut_{k + 1}_length_mm"]
            < 0.9 * full.stages.execute.figures[f"cut_{k + 1}_length_mm"]
        )


def test_tool_blade_length_comes_from_the_task_or_the_built_in_tool() -> None:
    from keymps.robot.description import tool_from_task

    def blade(tool: Any) -> float:
        task = make_task("knife", 0.02)
        spec = Task.model_validate({**task.model_dump(), "robot": {"tool": tool}})
        return tool_from_task(spec).blade_length

    assert blade("knife") == 0.16
    assert blade("piping_bag") == 0.0
    assert blade({"name": "knife", "blade_length": 0.2}) == 0.2
    assert blade({"name": "spatula", "tcp": [0, 0, 0.1]}) == 0.0
    for bad in (0.0, 0.5):
        with pytest.raises(ValueError, match="blade_length"):
            blade({"name": "knife", "blade_length": bad})


def test_a_sawing_blade_trails_the_cut_and_stays_inside_the_food() -> None:
    from keymps.default_plugins.sim.executor import Replay, marks
    from keymps.outcome.cut_sweep import Footprint, covered_length

    # sawing along +x: 10 mm strokes back and forth while descending through a 2 cm top
    s = np.linspace(0.0, 1.0, 2001)
    x = 0.10 + 0.08 * s + 0.005 * np.sin(2 * math.pi * 12 * s)
    xyz = np.column_stack([x, np.full_like(s, 0.09), 0.025 * (1 - s)])
    yaw_x = np.tile([1.0, 0.0], (len(s), 1))  # the knife's x axis along the cut
    replay = Replay(s, xyz, xyz, np.zeros(len(s), int), np.full(len(s), "work"), yaw_x)
    found = marks(replay, 0.02, blade_length=0.16)
    (sweep,) = found.sweeps
    assert np.all(sweep[:, 1, 0] < sweep[:, 0, 0])  # the edge points back, whichever stroke
    assert np.allclose(np.linalg.norm(sweep[:, 1] - sweep[:, 0], axis=1), 0.16)
    steps = np.linalg.norm(np.diff(sweep[:, 0], axis=0), axis=1)
    sample_step = np.linalg.norm(np.diff(xyz, axis=0), axis=1).max()
    assert steps.max() <= 0.0005 + sample_step  # a blade position every 0.5 mm of travel
    food = Footprint(np.array([[0.10, 0.07], [0.17, 0.07], [0.17, 0.11], [0.10, 0.11]]))
    assert covered_length(sweep, food) == pytest.approx(0.07, abs=0.001)  # the food's width
    # the tip alone is in the food only from x = 0.113 (the back end of its first stroke
    # after it went below the top at s = 0.2)
    tip_only = marks(replay, 0.02, blade_length=0.0).sweeps[0]
    assert covered_length(tip_only, food) == pytest.approx(0.17 - 0.113, abs=0.001)
