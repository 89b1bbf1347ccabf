"""The `ros2` executor: the validated trajectory as a control_msgs/FollowJointTrajectory goal,
sent through rosbridge (roslibpy) to a ROS 2 joint_trajectory_controller.

Sequence: connect to rosbridge, read the arm's joints from its joint-state topic, check that
the trajectory starts near them and that the move there passes keymps' safety check (the same
moveJ profile the ur-rtde executor uses); without --confirm stop there (a dry run). With
--confirm: send the move to the first sample as one goal, then the trajectory as another, and
wait for each result. Ctrl-C cancels the goal being executed.
"""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import replace
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from keymps.errors import KeympsError
from keymps.plugin import parse_options, require_validated
from keymps.types import ExecutionReport, Trajectory
from keymps_ros.messages import NamePart, RosName, joint_names

NAME = "ros2"
ACTION_TYPE = "control_msgs/action/FollowJointTrajectory"
SUCCEEDED = 4
STATUS = {
    1: "ACCEPTED",
    2: "EXECUTING",
    3: "CANCELING",
    4: "SUCCEEDED",
    5: "CANCELED",
    6: "ABORTED",
}
RESULT_MARGIN_S = 5.0
"""How long after a goal's duration (and goal_time_tolerance) its result may come."""


class Ros2Options(BaseModel):
    """The executor section of a task file for `ros2` (every key but `name`)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True)

    host: str = Field(min_length=1, description="the rosbridge server's address")
    port: int = Field(9090, ge=1, le=65535)
    action: RosName = "/scaled_joint_trajectory_controller/follow_joint_trajectory"
    joint_states_topic: RosName = "/joint_states"
    joint_prefix: NamePart = ""
    approach_speed: float = Field(0.25, gt=0, le=1.0)
    """Joint speed of the move to the first sample, rad/s."""
    approach_acceleration: float = Field(0.5, gt=0, le=1.4)
    max_start_offset: float = Field(0.35, gt=0, le=1.5)
    """Refuse when any joint is further than this from the first sample, rad."""
    path_tolerance: float = Field(0.2, gt=0, le=1.0)
    """The controller aborts when a joint strays further than this from the trajectory, rad."""
    goal_time_tolerance: float = Field(0.5, ge=0, le=10.0)
    timeout_s: float = Field(5.0, gt=0, le=60.0)
    """How long to wait for rosbridge and for the first joint state, s."""


class Ros2Executor:
    """Sends a validated trajectory to a ROS 2 controller; a dry run unless run.options.confirm."""

    name = NAME

    def __init__(self, options: Ros2Options):
        self.options = options

    def execute(self, validated: Any, run: Any) -> ExecutionReport:
        from keymps.robot.identity import arm_identity

        trajectory = require_validated(validated, self.name)
        confirm = bool(getattr(run.options, "confirm", False))
        mode = "--confirm" if confirm else "dry run"
        arm = arm_identity(run)
        try:
            if tuple(trajectory.joint_names) != arm.joint_names:
                raise KeympsError(
                    f"executor ros2: the trajectory's joints are not the {arm.model}'s"
                )
            report = self._connected(trajectory, run, confirm)
        except KeympsError as error:
            message = str(error).replace(f"executor {NAME}: ", f"executor {NAME} ({mode}): ", 1)
            report = ExecutionReport(self.name, False, message)
        return replace(report, dry_run=not confirm)

    def _connected(self, trajectory: Trajectory, run: Any, confirm: bool) -> ExecutionReport:
        ros = connect(self.options)
        try:
            where = f"{self.options.host}:{self.options.port}"
            actual = read_joints(ros, self.options, trajectory)
            offset, approach = self._check_start(actual, trajectory, run)
            figures = {
                "duration_s": trajectory.duration_s,
                "samples": float(trajectory.samples),
                "start_offset_rad": offset,
                "approach_s": approach.duration_s,
            }
            if not confirm:
                return ExecutionReport(
                    self.name,
                    True,
                    f"dry run: rosbridge at {where} answers, the arm's joints are {offset:.3f} rad "
                    "from the trajectory's first sample and the move there passes the safety "
                    "check; nothing was sent. Run again with --confirm to move the arm.",
                    (),
                    figures,
                )
            return self._move(ros, approach, trajectory, figures)
        finally:
            _close(ros)

    def _check_start(
        self, actual: np.ndarray, trajectory: Trajectory, run: Any
    ) -> tuple[float, Trajectory]:
        """The largest joint offset to the first sample and the checked move there."""
        from keymps.plugin import SafetyError
        from keymps.robot.approach import check_approach, move_j_profile
        from keymps.robot.model import RobotModel

        first = np.asarray(trajectory.q[0], dtype=float)
        offsets = np.abs(first - actual)
        worst = int(np.argmax(offsets))
        jog = f"jog the arm to [{', '.join(f'{v:.3f}' for v in first)}] rad first"
        if offsets[worst] > self.options.max_start_offset:
            raise KeympsError(
                f"executor ros2: the trajectory starts {offsets[worst]:.2f} rad away from the "
                f"arm's {trajectory.joint_names[worst]} (at most "
                f"{self.options.max_start_offset:.2f}); {jog}"
            )
        speed, acceleration = self.options.approach_speed, self.options.approach_acceleration
        try:
            check_approach(
                run.robot or RobotModel.from_task(run.task), actual, first, run.task,
                speed=speed, acceleration=acceleration, rate_hz=float(trajectory.rate_hz),
            )  # fmt: skip
        except SafetyError as error:
            raise KeympsError(f"executor ros2: refused before moving: {error}; {jog}") from None
        approach = move_j_profile(actual, first, speed, acceleration, float(trajectory.rate_hz))
        return float(offsets.max()), replace(approach, joint_names=trajectory.joint_names)

    def _move(
        self, ros: Any, approach: Trajectory, trajectory: Trajectory, figures: dict[str, float]
    ) -> ExecutionReport:
        import roslibpy

        client = roslibpy.ActionClient(ros, self.options.action, ACTION_TYPE)
        started = time.monotonic()
        for what, part in (
            ("the move to the first sample", approach),
            ("the trajectory", trajectory),
        ):
            outcome = run_goal(client, self.goal(part), part.duration_s + self._grace())
            if outcome is not None:
                figures["wall_time_s"] = time.monotonic() - started
                return ExecutionReport(
                    self.name, False, f"--confirm: {what} {outcome}", (), figures
                )
        figures["wall_time_s"] = time.monotonic() - started
        return ExecutionReport(
            self.name,
            True,
            f"--confirm: executed {trajectory.duration_s:.1f} s ({trajectory.samples} points) "
            f"through {self.options.action}",
            (),
            figures,
        )

    def _grace(self) -> float:
        return self.options.goal_time_tolerance + RESULT_MARGIN_S

    def goal(self, trajectory: Trajectory) -> dict[str, Any]:
        """A FollowJointTrajectory goal as rosbridge's JSON."""
        names = joint_names(trajectory, self.options.joint_prefix)
        tolerances = [
            {"name": name, "position": self.options.path_tolerance, "velocity": 0.0,
             "acceleration": 0.0}
            for name in names
        ]  # fmt: skip
        seconds, nanoseconds = divmod(round(self.options.goal_time_tolerance * 1e9), 10**9)
        return {
            "trajectory": joint_trajectory_json(trajectory, names),
            "path_tolerance": tolerances,
            "goal_tolerance": [],
            "goal_time_tolerance": {"sec": seconds, "nanosec": nanoseconds},
        }


def joint_trajectory_json(trajectory: Trajectory, names: list[str]) -> dict[str, Any]:
    """trajectory_msgs/JointTrajectory as rosbridge's JSON (header stamp zero: start now)."""
    from keymps.motion.trajectory_io import joint_trajectory_message

    if float(trajectory.t[0]) != 0.0:
        trajectory = replace(trajectory, t=np.asarray(trajectory.t) - trajectory.t[0])
    return {**joint_trajectory_message(trajectory), "joint_names": names}


def connect(options: Ros2Options) -> Any:
    """A roslibpy connection to rosbridge (asyncio transport: one per run, closed after)."""
    import roslibpy

    where = f"{options.host}:{options.port}"
    try:
        with socket.create_connection((options.host, options.port), timeout=options.timeout_s):
            pass
    except OSError as error:
        reason = "no answer" if isinstance(error, TimeoutError) else error.strerror or error
        raise KeympsError(
            f"executor ros2: cannot reach rosbridge at {where}: {reason}; is "
            "rosbridge_server running (ros2 launch rosbridge_server "
            "rosbridge_websocket_launch.xml) and executor.host its address?"
        ) from None
    ros = roslibpy.Ros(options.host, options.port, transport="asyncio")
    try:
        ros.run(timeout=options.timeout_s)
    except Exception as error:
        _close(ros)
        raise KeympsError(f"executor ros2: rosbridge at {where} did not connect: {error}") from None
    return ros


def read_joints(ros: Any, options: Ros2Options, trajectory: Trajectory) -> np.ndarray:
    """The arm's joints (in the trajectory's order) from the first joint state naming them all."""
    import roslibpy

    wanted = joint_names(trajectory, options.joint_prefix)
    seen: list[dict[str, Any]] = []
    arrived = threading.Event()

    def keep(message: dict[str, Any]) -> None:
        if not arrived.is_set():
            seen.append(message)
            arrived.set()

    topic = roslibpy.Topic(ros, options.joint_states_topic, "sensor_msgs/msg/JointState")
    topic.subscribe(keep)
    try:
        if not _wait(arrived, options.timeout_s):
            raise KeympsError(
                f"executor ros2: no sensor_msgs/JointState on {options.joint_states_topic} "
                f"within {options.timeout_s:g} s; is the robot's driver running?"
            )
    finally:
        topic.unsubscribe()
    message = seen[0]
    positions = dict(zip(message.get("name", []), message.get("position", []), strict=False))
    missing = [name for name in wanted if name not in positions]
    if missing:
        raise KeympsError(
            f"executor ros2: {options.joint_states_topic} names no {', '.join(missing)} "
            f"(it names {', '.join(positions) or 'nothing'}); set executor.joint_prefix"
        )
    return np.array([float(positions[name]) for name in wanted])


def run_goal(client: Any, goal: dict[str, Any], deadline_s: float) -> str | None:
    """Send `goal` and wait for its result: None when it succeeded, else what happened."""
    import roslibpy

    done = threading.Event()
    outcome: dict[str, Any] = {}

    def finished(result: Any) -> None:
        outcome["result"] = result
        done.set()

    goal_id = client.send_goal(roslibpy.Goal(goal), finished, lambda _: None, finished)
    try:
        if not _wait(done, deadline_s):
            client.cancel_goal(goal_id)
            return f"had no result within {deadline_s:.1f} s"
    except KeyboardInterrupt:
        client.cancel_goal(goal_id)
        _wait(done, 2.0)  # the cancellation's result, if the controller sends it in time
        return "was stopped by Ctrl-C: the goal was cancelled"
    return _failure(outcome["result"])


def _failure(result: Any) -> str | None:
    status = result.get("status")
    code = getattr(status, "value", status)
    values = result.get("values") or {}
    error = values.get("error_code", 0) if isinstance(values, dict) else 0
    if code == SUCCEEDED and not error:
        return None
    words = values.get("error_string", "") if isinstance(values, dict) else ""
    return (
        f"ended {STATUS.get(code, code)} (error_code {error}"
        + (f": {words}" if words else "")
        + ")"
    )


def _wait(event: threading.Event, seconds: float) -> bool:
    """event.wait in short steps, so that Ctrl-C is taken at once."""
    deadline = time.monotonic() + seconds
    while not event.is_set():
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        event.wait(min(left, 0.05))
    return True


def _close(ros: Any) -> None:
    try:
        ros.close(timeout=2)
    except Exception:  # already gone: nothing left to close
        return


def make_executor(options: dict[str, Any]) -> Ros2Executor:
    return Ros2Executor(parse_options(Ros2Options, options, "executor ros2"))
