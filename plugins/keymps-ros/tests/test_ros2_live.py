"""The ros2 executor against a fake rosbridge server on 127.0.0.1 (fake_rosbridge.py, its own
process): the real roslibpy client, the real rosbridge JSON protocol over a websocket.

Not tested here, because no ROS 2 is installed: a real rosbridge_server translating the goal
into ROS 2 (its field defaults, QoS), a real joint_trajectory_controller (how it interpolates
from the arm's state, its tolerances, its cancel handling), and an arm. Try a new setup with
URSim or a mock hardware controller (ros2_control's mock_components) before a real arm.
"""

from __future__ import annotations

import _thread
import json
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from keymps.config.task import Task
from keymps.errors import KeympsError
from keymps.motion.timing import time_trajectory
from keymps.plugin.manager import create_component
from keymps.robot.model import RobotModel, solve_path
from keymps.robot.safety import SafetyError, validate
from keymps.run import Run, RunOptions
from keymps.types import Piece, ToolPath, ValidatedTrajectory

HERE = Path(__file__).resolve().parent


def make_task() -> Task:
    return Task.model_validate(
        {
            "name": "line",
            "instruction": "icing",
            "scene": {"image": "x.png", "object_height": 0.06},
            "primitives": ["line"],
            "robot": {"model": "ur3e", "tool": "piping_bag"},
        }
    )


@pytest.fixture(scope="module")
def validated() -> ValidatedTrajectory:
    """A real, validated 3 cm line above the board (about half a second)."""
    task = make_task()
    model = RobotModel.from_task(task)
    points = np.array([0.14, 0.09, 0.065]) + np.linspace(0, 0.03, 31)[:, None] * [1.0, 0, 0]
    path = ToolPath((Piece("work", 0, points, np.zeros(31), 0.1),), "line")
    trajectory = time_trajectory(model, path, solve_path(model, path), task)
    outline = np.array([[0.09, 0.04], [0.21, 0.04], [0.21, 0.14], [0.09, 0.14]])
    return validate(model, trajectory, path, outline, task)


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


class Bridge:
    """The fake rosbridge process and what it received."""

    def __init__(self, tmp: Path, joints: list[float], names: list[str], mode: str = "ok"):
        self.port, self.log = free_port(), tmp / f"bridge-{mode}.jsonl"
        self.log.touch()
        self.process = subprocess.Popen(
            [sys.executable, str(HERE / "fake_rosbridge.py"), str(self.port), str(self.log),
             json.dumps(joints), json.dumps(names), mode],
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert self.process.stdout is not None
        assert self.process.stdout.readline().strip() == "ready"

    def received(self, op: str) -> list[dict[str, Any]]:
        lines = self.log.read_text().splitlines()
        return [m for m in map(json.loads, lines) if m.get("op") == op]

    def stop(self) -> None:
        self.process.terminate()
        self.process.wait(10)


@pytest.fixture
def near_start(tmp_path: Path, validated: ValidatedTrajectory) -> Iterator[Bridge]:
    """A bridge whose arm is 0.05 rad from the trajectory's first point."""
    joints = (validated.trajectory.q[0] + 0.05).tolist()
    bridge = Bridge(tmp_path, joints, list(validated.trajectory.joint_names))
    yield bridge
    bridge.stop()


def make_run(tmp_path: Path, confirm: bool) -> Run:
    task = make_task()
    return Run(task, tmp_path, RunOptions(confirm=confirm), robot=RobotModel.from_task(task))


def executor(bridge: Bridge, **options: Any) -> Any:
    return create_component(
        "executor", "ros2", {"host": "127.0.0.1", "port": bridge.port, **options}
    )


def test_dry_run_reads_the_arm_and_sends_no_goal(
    tmp_path: Path, near_start: Bridge, validated: ValidatedTrajectory
) -> None:
    report = executor(near_start).execute(validated, make_run(tmp_path, confirm=False))
    assert report.ok and report.dry_run is True, report.message
    assert report.message.startswith(f"dry run: rosbridge at 127.0.0.1:{near_start.port} answers")
    assert report.figures["start_offset_rad"] == pytest.approx(0.05)
    assert near_start.received("subscribe")[0]["topic"] == "/joint_states"
    assert near_start.received("send_action_goal") == []


def test_confirm_sends_the_approach_then_the_trajectory_exactly(
    tmp_path: Path, near_start: Bridge, validated: ValidatedTrajectory
) -> None:
    report = executor(near_start).execute(validated, make_run(tmp_path, confirm=True))
    assert report.ok and report.dry_run is False, report.message
    approach, goal = near_start.received("send_action_goal")
    action = "/scaled_joint_trajectory_controller/follow_joint_trajectory"
    for sent in (approach, goal):
        assert sent["action"] == action
        assert sent["action_type"] == "control_msgs/action/FollowJointTrajectory"
    trajectory = validated.trajectory
    first = approach["args"]["trajectory"]["points"]
    assert np.allclose(first[0]["positions"], trajectory.q[0] + 0.05)
    assert first[-1]["positions"] == trajectory.q[0].tolist()
    speeds = np.abs(np.diff([p["positions"] for p in first], axis=0)).max() * trajectory.rate_hz
    assert speeds <= 0.25 + 1e-9  # the approach at its slow speed
    sent = goal["args"]["trajectory"]
    assert sent["joint_names"] == list(trajectory.joint_names)
    assert sent["header"]["stamp"] == {"sec": 0, "nanosec": 0}
    assert np.array_equal(np.array([p["positions"] for p in sent["points"]]), trajectory.q)
    assert np.array_equal(np.array([p["velocities"] for p in sent["points"]]), trajectory.qd)
    stamps = [p["time_from_start"]["sec"] * 10**9 + p["time_from_start"]["nanosec"]
              for p in sent["points"]]  # fmt: skip
    assert stamps == np.rint(trajectory.t * 1e9).astype(np.int64).tolist()
    tolerance = goal["args"]["path_tolerance"]
    assert {t["name"] for t in tolerance} == set(trajectory.joint_names)
    assert all(t["position"] == 0.2 for t in tolerance)
    assert report.figures["wall_time_s"] >= trajectory.duration_s


def test_a_start_far_from_the_arm_is_refused_before_any_goal(
    tmp_path: Path, validated: ValidatedTrajectory
) -> None:
    joints = (validated.trajectory.q[0] + [0.0, 0.0, 0.6, 0, 0, 0]).tolist()
    bridge = Bridge(tmp_path, joints, list(validated.trajectory.joint_names))
    try:
        report = executor(bridge).execute(validated, make_run(tmp_path, confirm=True))
    finally:
        bridge.stop()
    assert not report.ok and report.dry_run is False
    assert report.message.startswith(
        "executor ros2 (--confirm): the trajectory starts 0.60 rad away from the arm's elbow_joint"
    )
    assert bridge.received("send_action_goal") == []


def test_joint_names_the_driver_does_not_use_are_one_line(
    tmp_path: Path, validated: ValidatedTrajectory
) -> None:
    names = [f"ur_{name}" for name in validated.trajectory.joint_names]
    bridge = Bridge(tmp_path, validated.trajectory.q[0].tolist(), names)
    try:
        report = executor(bridge).execute(validated, make_run(tmp_path, confirm=True))
        assert "names no shoulder_pan_joint" in report.message
        assert report.message.endswith("set executor.joint_prefix")
        report = executor(bridge, joint_prefix="ur_").execute(validated, make_run(tmp_path, True))
        assert report.ok, report.message
        assert bridge.received("send_action_goal")[-1]["args"]["trajectory"]["joint_names"] == names
    finally:
        bridge.stop()


def test_an_aborted_goal_is_a_failed_execution(
    tmp_path: Path, validated: ValidatedTrajectory
) -> None:
    bridge = Bridge(
        tmp_path,
        validated.trajectory.q[0].tolist(),
        list(validated.trajectory.joint_names),
        "abort",
    )
    try:
        report = executor(bridge).execute(validated, make_run(tmp_path, confirm=True))
    finally:
        bridge.stop()
    assert not report.ok
    assert report.message == (
        "--confirm: the move to the first sample ended ABORTED (error_code -4: path tolerance "
        "violated)"
    )
    assert len(bridge.received("send_action_goal")) == 1  # nothing after a failed goal


def test_ctrl_c_cancels_the_goal(tmp_path: Path, validated: ValidatedTrajectory) -> None:
    # the arm's wrist 0.3 rad away: the move to the first sample takes about 1.7 s; a real
    # interrupt of the main thread (what SIGINT raises) as soon as the bridge has the goal
    joints = (validated.trajectory.q[0] + [0, 0, 0, 0, 0, 0.3]).tolist()
    bridge = Bridge(tmp_path, joints, list(validated.trajectory.joint_names))
    interrupter = threading.Thread(target=_interrupt_on_goal, args=(bridge,), daemon=True)
    interrupter.start()
    try:
        report = executor(bridge).execute(validated, make_run(tmp_path, confirm=True))
    finally:
        bridge.stop()
    assert not report.ok
    assert report.message == (
        "--confirm: the move to the first sample was stopped by Ctrl-C: the goal was cancelled"
    )
    [goal] = bridge.received("send_action_goal")
    [cancel] = bridge.received("cancel_action_goal")
    assert cancel["id"] == goal["id"]


def _interrupt_on_goal(bridge: Bridge) -> None:
    while not bridge.received("send_action_goal"):
        threading.Event().wait(0.005)
    _thread.interrupt_main()


def test_no_rosbridge_is_one_line_at_once(tmp_path: Path, validated: ValidatedTrajectory) -> None:
    options = {"host": "127.0.0.1", "port": free_port()}
    report = create_component("executor", "ros2", options).execute(
        validated, make_run(tmp_path, confirm=True)
    )
    assert not report.ok
    assert report.message.startswith(
        f"executor ros2 (--confirm): cannot reach rosbridge at 127.0.0.1:{options['port']}: "
        "Connection refused; is rosbridge_server running"
    )


def test_unvalidated_trajectories_are_refused(
    tmp_path: Path, validated: ValidatedTrajectory
) -> None:
    copy = ValidatedTrajectory(validated.trajectory, validated.report)
    with pytest.raises(SafetyError):
        create_component("executor", "ros2", {"host": "127.0.0.1"}).execute(
            copy, make_run(tmp_path, confirm=True)
        )


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({}, "option 'host': required (the rosbridge server's address)"),
        ({"host": "h", "action": "follow"}, "is not an absolute ROS name"),
        ({"host": "h", "port": 0}, "greater than or equal to 1"),
        ({"host": "h", "approach_speed": 3}, "less than or equal to 1"),
    ],
)
def test_bad_options_are_one_line(options: dict[str, Any], message: str) -> None:
    with pytest.raises(KeympsError) as error:
        create_component("executor", "ros2", options)
    assert str(error.value).startswith("executor ros2: ") and message in str(error.value)
