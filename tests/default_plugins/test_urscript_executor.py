"""The urscript executor: programs read back with a URScript reader and compared with the
trajectory (joints to 1e-6 rad, times to the ns), on real validated trajectories and on
hundreds of generated ones; refusals in one line."""

from __future__ import annotations

import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from helpers.robot_toolpaths import radial_cuts, ring_of_dots
from helpers.urscript_reader import Program, read_urscript

from keymps.config.task import Task
from keymps.default_plugins.urscript import (
    UrScriptOptions,
    between,
    build_program,
    waypoints,
)
from keymps.errors import KeympsError
from keymps.motion.timing import time_trajectory
from keymps.plugin import trajectory_digest
from keymps.plugin.manager import create_component
from keymps.robot import identity
from keymps.robot.identity import ArmIdentity
from keymps.robot.model import RobotModel, solve_path
from keymps.robot.safety import SafetyError, validate
from keymps.run import Run, RunOptions, RunOverrides
from keymps.types import Trajectory, ValidatedTrajectory

JOINTS = 1e-6
"""rad: how closely the program's joints must match the trajectory's (9 decimals are written)."""
UR3 = ArmIdentity("ur3", "Universal Robots", identity.JOINT_NAMES, 125.0, "CB3")
UR3E = ArmIdentity("ur3e", "Universal Robots", identity.JOINT_NAMES, 500.0, "e-Series")


def make_task(model: str, tool: str, name: str = "cake icing", rate: float | None = None) -> Task:
    robot: dict[str, object] = {"model": model, "tool": tool}
    if rate is not None:
        robot["rate_hz"] = rate
    return Task.model_validate(
        {
            "name": name,
            "instruction": "do it",
            "scene": {"image": "x.png", "object_height": 0.06 if tool == "piping_bag" else 0.02},
            "primitives": ["line"],
            "robot": robot,
        }
    )


@cache
def _planned(model: str, tool: str, rate: float | None) -> tuple[RobotModel, Trajectory, object]:
    task = make_task(model, tool, rate=rate)
    robot = RobotModel.from_task(task)
    path = ring_of_dots(count=4) if tool == "piping_bag" else radial_cuts(count=3, top=0.025)
    return robot, time_trajectory(robot, path, solve_path(robot, path), task), path


def validated_run(
    folder: Path, model: str = "ur3", tool: str = "piping_bag", name: str = "cake icing",
    rate: float | None = None,
) -> tuple[ValidatedTrajectory, Run]:  # fmt: skip
    """A real trajectory through keymps' safety check, and a run of it in `folder`."""
    robot, trajectory, path = _planned(model, tool, rate)
    task = make_task(model, tool, name, rate)
    radius = 0.06 if tool == "piping_bag" else 0.09
    angles = np.linspace(0, 2 * math.pi, 72, endpoint=False)
    outline = np.column_stack([0.15 + radius * np.cos(angles), 0.09 + radius * np.sin(angles)])
    validated = validate(robot, trajectory, path, outline, task)  # type: ignore[arg-type]
    assert validated.report.ok, validated.report.problems
    return validated, Run(task=task, folder=folder, robot=robot)


def check_servoj(program: Program, trajectory: Trajectory, arm: ArmIdentity, lookahead: float,
                 gain: float) -> None:  # fmt: skip
    """Every sample is one servoj at its own time after the movej to the first one."""
    q, t = np.asarray(trajectory.q), np.asarray(trajectory.t)
    motions = [c for c in program.calls if c.name in ("movej", "servoj", "stopj")]
    assert [c.name for c in motions] == ["movej"] + ["servoj"] * len(q) + ["stopj"]
    approach, servos = motions[0], motions[1:-1]
    assert np.abs(approach.joints() - q[0]).max() <= JOINTS
    streamed = np.array([c.joints() for c in servos])
    assert np.abs(streamed[:-1] - q[1:]).max(initial=0) <= JOINTS
    assert np.abs(streamed[-1] - q[-1]).max() <= JOINTS  # the hold at the end
    steps = np.array([c.number("t") for c in servos])
    assert np.abs(np.cumsum(steps[:-1]) - (t[1:] - t[0])).max(initial=0) <= 1e-9 * len(t)
    cycle = 1.0 / arm.controller_hz
    assert np.allclose(steps / cycle, np.round(steps / cycle), atol=1e-6)  # whole cycles
    assert steps[-1] >= lookahead and steps[-1] - cycle < lookahead
    for call in servos:
        assert call.args[1:] == [0.0, 0.0]  # a and v: unused by the controller
        assert call.number("lookahead_time") == lookahead and call.number("gain") == gain


def test_servoj_program_reads_back_as_the_validated_trajectory(tmp_path: Path) -> None:
    validated, run = validated_run(tmp_path, "ur3e")
    executor = create_component("executor", "urscript", {"lookahead_time": 0.05, "gain": 500})
    report = executor.execute(validated, run)
    assert report.ok and report.files == (str(tmp_path / "trajectory.script"),)
    assert report.dry_run is None and "nothing was sent" in report.message
    trajectory = validated.trajectory
    program = read_urscript((tmp_path / "trajectory.script").read_text())
    check_servoj(program, trajectory, UR3E, 0.05, 500.0)
    assert program.name == "keymps_cake_icing"
    assert program.comment("trajectory sha256:") == trajectory_digest(trajectory)
    assert program.comment("task:") == "cake icing"
    assert program.comment("keymps ").startswith("0.")
    assert program.calls[-1].name == "textmsg"
    approach = program.named("movej")[0]
    assert approach.number("v") == 0.25 and approach.number("a") == 0.5
    assert report.figures["commands"] == trajectory.samples


def test_cb3_program_streams_at_125_hz_and_e_series_accepts_slower_rates(tmp_path: Path) -> None:
    validated, run = validated_run(tmp_path / "cb3", "ur3")
    create_component("executor", "urscript", {}).execute(validated, run)
    program = read_urscript((tmp_path / "cb3" / "trajectory.script").read_text())
    check_servoj(program, validated.trajectory, UR3, 0.1, 300.0)
    assert {c.number("t") for c in program.named("servoj")[:-1]} == {0.008}
    validated, run = validated_run(tmp_path / "e", "ur3e", rate=125.0)  # 4 cycles a sample
    create_component("executor", "urscript", {}).execute(validated, run)
    program = read_urscript((tmp_path / "e" / "trajectory.script").read_text())
    check_servoj(program, validated.trajectory, UR3E, 0.1, 300.0)


def test_generated_trajectories_read_back_exactly(fuzz_counter) -> None:  # type: ignore[no-untyped-def]
    """300 trajectories of any length, joint range, rate and arm the controller accepts."""
    rng = np.random.default_rng(20260501)
    for case in range(300):
        arm = UR3 if case % 2 else UR3E
        rate = arm.controller_hz / int(rng.choice([1, 2, 4, 5]))
        samples = int(rng.integers(2, 300))
        trajectory = synthetic(rng, samples, rate)
        options = UrScriptOptions(
            lookahead_time=float(rng.uniform(0.03, 0.2)), gain=float(rng.integers(100, 2001))
        )
        text, figures = build_program(trajectory, arm, options, f"case {case}")
        check_servoj(read_urscript(text), trajectory, arm, options.lookahead_time, options.gain)
        assert figures["commands"] == samples
        fuzz_counter.add("urscript servoj readback", text.encode(), "read back")


def synthetic(rng: np.random.Generator, samples: int, rate: float) -> Trajectory:
    """A smooth random joint trajectory (any values within +-2 pi) sampled at `rate`."""
    t = np.arange(samples) / rate
    knots = rng.uniform(-2 * math.pi, 2 * math.pi, (6, 6))
    q = np.column_stack([np.interp(t, np.linspace(0, t[-1], 6), k) for k in knots])
    q[rng.random(q.shape) < 0.01] *= -1e-7  # tiny and negative zero values too
    pieces = np.sort(rng.integers(0, 5, samples))
    return Trajectory(
        t, q, np.zeros_like(q), np.zeros_like(q), np.zeros((samples, 3)), pieces,
        np.where(pieces % 2, "work", "travel"), identity.JOINT_NAMES, rate,
    )  # fmt: skip


def test_waypoint_program_meets_its_tolerance_on_generated_trajectories(fuzz_counter) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(7)
    for case in range(200):
        trajectory = synthetic(rng, int(rng.integers(2, 600)), 125.0)
        tolerance = float(rng.choice([0.0005, 0.001, 0.01]))
        options = UrScriptOptions(mode="waypoints", waypoint_tolerance=tolerance)
        program = read_urscript(build_program(trajectory, UR3, options, "w")[0])
        q, t = np.asarray(trajectory.q), np.asarray(trajectory.t)
        moves = program.named("movej")[1:]
        targets = np.array([c.joints() for c in moves]).reshape(-1, 6)
        times = t[0] + np.cumsum([c.number("t") for c in moves])
        kept = np.searchsorted(t, times - 1e-7)
        assert np.abs(t[kept] - times).max(initial=0) <= 1e-6  # every move ends on a sample
        assert np.abs(targets - q[kept]).max(initial=0) <= JOINTS  # ... at its joints
        assert all(c.kwargs["r"] == 0.0 for c in moves)
        path = between(q, t, [0, *kept.tolist()])
        assert np.abs(path - q).max() <= tolerance + JOINTS
        ends = np.flatnonzero(np.diff(trajectory.piece_index))
        assert set(ends.tolist()) <= {0, *kept.tolist()}  # every piece ends on a waypoint
        fuzz_counter.add("urscript waypoints readback", (case, tolerance), "within tolerance")


def test_waypoint_executor_reports_how_far_the_tool_strays(tmp_path: Path) -> None:
    validated, run = validated_run(tmp_path, "ur3", tool="knife")
    report = create_component(
        "executor", "urscript", {"mode": "waypoints", "file": "arm/cuts.script"}
    ).execute(validated, run)
    assert report.files == (str(tmp_path / "arm" / "cuts.script"),)
    program = read_urscript((tmp_path / "arm" / "cuts.script").read_text())
    kept = waypoints(validated.trajectory, 0.001)
    assert len(program.named("movej")) == len(kept)  # the approach, then one per waypoint
    assert report.figures["max_waypoint_deviation_rad"] <= 0.001
    assert 0 < report.figures["max_waypoint_tool_deviation_mm"] < 1.0
    assert report.figures["commands"] < validated.trajectory.samples / 3


def test_a_hostile_task_name_cannot_add_code(tmp_path: Path) -> None:
    # the task model already refuses control characters (so no new line); quotes, brackets and
    # letters beyond ASCII it allows
    name = 'Torte für "x") movej([0,0,0,0,0,0]) textmsg("y'
    validated, run = validated_run(tmp_path, name=name)
    create_component("executor", "urscript", {}).execute(validated, run)
    program = read_urscript((tmp_path / "trajectory.script").read_text())
    assert program.name == "keymps_torte_f_r_x_movej_0_0_0_0_0_0_textmsg_y"
    assert program.comment("task:") == "Torte f?r ?x?? movej??0?0?0?0?0?0?? textmsg??y"
    assert {c.name for c in program.calls} == {"textmsg", "movej", "servoj", "stopj"}
    assert len(program.named("movej")) == 1


def test_a_rate_that_is_no_whole_number_of_controller_cycles_is_refused(tmp_path: Path) -> None:
    validated, run = validated_run(tmp_path, "ur3", rate=500.0)  # 2 ms samples on a 8 ms CB3
    with pytest.raises(KeympsError) as error:
        create_component("executor", "urscript", {}).execute(validated, run)
    assert str(error.value) == (
        "executor urscript: samples 0 and 1 are 0.002000 s apart, not a whole number of the "
        "ur3 controller's 0.008 s cycles: set robot.rate_hz to 125 (or a divisor of it) or use "
        "mode: waypoints"
    )
    assert not (tmp_path / "trajectory.script").exists()
    report = create_component("executor", "urscript", {"mode": "waypoints"}).execute(validated, run)
    assert report.ok


def test_an_arm_of_another_maker_is_refused(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # keymps plans only for UR arms today; the robots plugins add others through arm_identity
    validated, run = validated_run(tmp_path)
    panda = ArmIdentity("panda", "Franka Robotics", UR3.joint_names, 1000.0, "FR3")
    monkeypatch.setattr(identity, "arm_identity", lambda run: panda)
    with pytest.raises(KeympsError, match=r"^executor urscript: the run's arm is a Franka "):
        create_component("executor", "urscript", {}).execute(validated, run)
    assert not (tmp_path / "trajectory.script").exists()


def test_unvalidated_or_edited_trajectories_are_refused(tmp_path: Path) -> None:
    validated, run = validated_run(tmp_path)
    executor = create_component("executor", "urscript", {})
    copy = ValidatedTrajectory(validated.trajectory, validated.report)
    with pytest.raises(SafetyError, match="did not come from keymps.robot.safety.validate"):
        executor.execute(copy, run)
    assert not (tmp_path / "trajectory.script").exists()


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"file": "/tmp/x.script"}, "leads out of the run folder"),
        ({"file": "../x.script"}, "leads out of the run folder"),
        ({"mode": "movel"}, "Input should be 'servoj' or 'waypoints'"),
        ({"gain": 50}, "greater than or equal to 100"),
        ({"lookahead_time": 0.5}, "less than or equal to 0.2"),
        ({"host": "10.0.0.2"}, "unknown option"),
    ],
)
def test_bad_options_are_one_line(options: dict[str, object], message: str) -> None:
    with pytest.raises(KeympsError) as error:
        create_component("executor", "urscript", options)
    text = str(error.value)
    assert text.startswith("executor urscript: option ") and message in text
    assert "\n" not in text


def test_a_write_that_fails_is_one_line(tmp_path: Path) -> None:
    validated, run = validated_run(tmp_path)
    (tmp_path / "trajectory.script").mkdir()  # a folder where the file goes
    with pytest.raises(KeympsError, match=r"trajectory.script: cannot write: Is a directory$"):
        create_component("executor", "urscript", {}).execute(validated, run)


def test_the_same_trajectory_gives_the_same_bytes(tmp_path: Path) -> None:
    validated, run = validated_run(tmp_path / "a")
    create_component("executor", "urscript", {}).execute(validated, run)
    again, run = validated_run(tmp_path / "b")
    create_component("executor", "urscript", {}).execute(again, run)
    first = (tmp_path / "a" / "trajectory.script").read_bytes()
    assert first == (tmp_path / "b" / "trajectory.script").read_bytes()


def test_a_whole_run_writes_the_program_of_its_own_trajectory(tmp_path: Path) -> None:
    import json

    from keymps import run_task
    from keymps.motion.trajectory_io import read_trajectory_csv

    repo = Path(__file__).resolve().parents[2]
    run = run_task(repo / "tasks" / "cake_icing.yaml", options=RunOptions(rerun="off"), overrides=RunOverrides(executor="urscript", backend="offline", out=tmp_path / "run"))  # fmt: skip
    record = json.loads((run.folder / "run.json").read_text())["execution"]
    assert record["ok"] and record["files"] == [str(run.folder / "trajectory.script")]
    assert run.stages.check is not None
    trajectory = run.stages.check.trajectory
    program = read_urscript((run.folder / "trajectory.script").read_text())
    check_servoj(program, trajectory, UR3, 0.1, 300.0)
    assert program.comment("trajectory sha256:") == trajectory_digest(trajectory)
    table = read_trajectory_csv(run.folder / "trajectory.csv")  # the run folder's own record
    servos = np.array([c.joints() for c in program.named("servoj")[:-1]])
    assert np.abs(servos - table["q"][1:]).max() <= JOINTS
