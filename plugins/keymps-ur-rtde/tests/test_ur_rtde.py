"""The ur-rtde executor against a fake controller; no real arm is (or can be) connected here.

The receive side is the real ur_rtde library talking RTDE over TCP to a fake controller
(fake_rtde_server.py) in a separate process on a 127.0.0.x address. The control side, which
would upload a URScript and move a physical arm, is an autospec of
rtde_control.RTDEControlInterface: its calls are checked, and the fake "arm" follows the
servoJ commands through the shared state.
"""

from __future__ import annotations

import math
import random
import re
import time
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path
from typing import Any
from unittest import mock

import fake_rtde_server
import numpy as np
import pytest
import rtde_control

from keymps.config.task import Task
from keymps.errors import KeympsError
from keymps.motion.timing import time_trajectory
from keymps.plugin.manager import components, create_component
from keymps.robot.model import RobotModel, solve_path
from keymps.robot.safety import SafetyError, validate
from keymps.run import Run, RunOptions
from keymps.types import Piece, ToolPath, ValidatedTrajectory

HOST = f"127.0.0.{random.randint(20, 250)}"


@pytest.fixture(scope="module")
def arm() -> Iterator[fake_rtde_server.ArmState]:
    state = fake_rtde_server.ArmState([0.0] * 6)
    process = fake_rtde_server.start(HOST, state)
    yield state
    process.terminate()
    process.join(5)


@pytest.fixture(scope="module")
def validated() -> ValidatedTrajectory:
    """A real, validated 3 cm line above the board (about half a second at 125 Hz)."""
    task = Task.model_validate(
        {
            "name": "t",
            "instruction": "icing",
            "scene": {"image": "x.png", "object_height": 0.06},
            "primitives": ["line"],
            "robot": {"tool": "piping_bag"},
        }
    )
    model = RobotModel.from_task(task)
    start = np.array([0.14, 0.09, 0.065])
    points = start + np.linspace(0, 0.03, 31)[:, None] * [1.0, 0.0, 0.0]
    path = ToolPath((Piece("work", 0, points, np.zeros(31), 0.1),), "line")
    trajectory = time_trajectory(model, path, solve_path(model, path), task)
    outline = np.array([[0.09, 0.04], [0.21, 0.04], [0.21, 0.14], [0.09, 0.14]])
    return validate(model, trajectory, path, outline, task)


@pytest.fixture
def at_start(arm: fake_rtde_server.ArmState, validated: ValidatedTrajectory) -> Any:
    """The fake arm running, safe, a little away from the trajectory's first point."""
    arm.q[:] = list(validated.trajectory.q[0] + 0.05)
    arm.robot_mode.value = 7
    arm.safety_mode.value = 1
    time.sleep(0.02)
    return arm


def make_run(tmp_path: Path, confirm: bool) -> Run:
    task = Task.model_validate(
        {"name": "t", "instruction": "x", "scene": {"image": "x.png"}, "primitives": ["line"]}
    )
    return Run(task=task, folder=tmp_path, options=RunOptions(confirm=confirm))


def fake_control(arm: fake_rtde_server.ArmState, period: float = 1 / 125) -> Any:
    """An autospec of the control interface whose 'arm' follows moveJ and servoJ."""
    control = mock.create_autospec(rtde_control.RTDEControlInterface, instance=True)

    def move(q: list[float], *args: Any) -> bool:
        arm.q[:] = list(q)
        time.sleep(0.02)  # let the receive stream report the new joints
        return True

    def servo(q: list[float], *args: Any) -> bool:
        arm.q[:] = list(q)
        return True

    control.moveJ.side_effect = move
    control.servoJ.side_effect = servo
    control.getAsyncOperationProgress.return_value = -1
    control.initPeriod.side_effect = lambda: timedelta(seconds=time.monotonic())
    control.waitPeriod.side_effect = lambda start: time.sleep(
        max(0.0, start.total_seconds() + period - time.monotonic())
    )
    return control


def executor(control: Any = None, **options: Any) -> Any:
    from keymps_ur_rtde.executor import UrRtdeExecutor, UrRtdeOptions

    never = mock.Mock(side_effect=AssertionError("the control interface must not be used"))
    return UrRtdeExecutor(
        UrRtdeOptions(host=HOST, **options),
        connect_control=(lambda host, rate: control) if control is not None else never,
    )


def test_the_plugin_registers_through_its_entry_point() -> None:
    assert "ur-rtde" in components("executor")
    with pytest.raises(
        KeympsError, match=r"executor ur-rtde: option 'host': required \(the arm's IP address\)"
    ):
        create_component("executor", "ur-rtde", {})
    with pytest.raises(KeympsError, match="executor ur-rtde: option 'gain': "):
        create_component("executor", "ur-rtde", {"host": HOST, "gain": 5})
    assert create_component("executor", "ur-rtde", {"host": HOST}).options.host == HOST


def test_dry_run_checks_the_arm_and_moves_nothing(
    at_start: Any, validated: ValidatedTrajectory, tmp_path: Path
) -> None:
    report = executor().execute(validated, make_run(tmp_path, confirm=False))
    assert report.ok
    assert report.message.startswith("dry run")
    assert "--confirm" in report.message
    assert report.figures["start_offset_rad"] == pytest.approx(0.05, abs=1e-6)


def test_confirm_moves_to_the_start_slowly_then_streams_every_sample(
    at_start: Any, validated: ValidatedTrajectory, tmp_path: Path
) -> None:
    control = fake_control(at_start)
    trajectory = validated.trajectory
    report = executor(control).execute(validated, make_run(tmp_path, confirm=True))
    assert report.ok, report.message
    control.moveJ.assert_called_once()
    target, speed, acceleration, asynchronous = control.moveJ.call_args.args
    assert target == pytest.approx(list(trajectory.q[0]))
    assert (speed, acceleration, asynchronous) == (0.25, 0.5, True)
    assert control.servoJ.call_count == trajectory.samples
    for call, q in zip(control.servoJ.call_args_list, trajectory.q, strict=True):
        sent, _, _, period, lookahead, gain = call.args
        assert sent == pytest.approx(list(q))
        assert (period, lookahead, gain) == (pytest.approx(1 / 125), 0.1, 300.0)
    control.servoStop.assert_called_once()
    control.stopScript.assert_called_once()
    # streamed in real time at the controller rate
    assert report.figures["wall_time_s"] >= trajectory.duration_s


def test_refuses_a_trajectory_far_from_the_arm(
    at_start: Any, validated: ValidatedTrajectory, tmp_path: Path
) -> None:
    at_start.q[2] = float(validated.trajectory.q[0][2] + 1.0)
    time.sleep(0.02)
    report = executor().execute(validated, make_run(tmp_path, confirm=True))
    assert not report.ok and report.dry_run is False
    assert re.search(r"starts 1\.00 rad away from the arm's elbow_joint", report.message)


def test_refuses_an_arm_that_is_not_running_or_not_safe(
    at_start: Any, validated: ValidatedTrajectory, tmp_path: Path
) -> None:
    at_start.robot_mode.value = 5
    time.sleep(0.02)
    report = executor().execute(validated, make_run(tmp_path, confirm=False))
    assert not report.ok and "is IDLE, not RUNNING" in report.message
    at_start.robot_mode.value = 7
    at_start.safety_mode.value = 3
    time.sleep(0.02)
    report = executor().execute(validated, make_run(tmp_path, confirm=False))
    assert not report.ok and "safety mode PROTECTIVE_STOP" in report.message


def test_a_protective_stop_while_streaming_stops_the_arm(
    at_start: Any, validated: ValidatedTrajectory, tmp_path: Path
) -> None:
    control = fake_control(at_start)
    follow = control.servoJ.side_effect

    def servo(q: list[float], *args: Any) -> bool:
        if control.servoJ.call_count == 20:
            at_start.safety_mode.value = 3
            time.sleep(0.03)
        return bool(follow(q, *args))

    control.servoJ.side_effect = servo
    report = executor(control).execute(validated, make_run(tmp_path, confirm=True))
    assert not report.ok
    assert "safety mode PROTECTIVE_STOP" in report.message
    assert control.servoJ.call_count == 20
    control.servoStop.assert_called_once()
    control.stopScript.assert_called_once()


@pytest.mark.parametrize(
    ("failure", "expected"),
    [(KeyboardInterrupt(), "stopped by Ctrl-C"), (RuntimeError("RTDE lost"), "error: RTDE lost")],
)
def test_ctrl_c_or_an_error_stops_the_arm(
    failure: BaseException,
    expected: str,
    at_start: Any,
    validated: ValidatedTrajectory,
    tmp_path: Path,
) -> None:
    control = fake_control(at_start)
    follow = control.servoJ.side_effect

    def servo(q: list[float], *args: Any) -> bool:
        if control.servoJ.call_count == 10:
            raise failure
        return bool(follow(q, *args))

    control.servoJ.side_effect = servo
    run = make_run(tmp_path, confirm=True)
    if isinstance(failure, KeyboardInterrupt):  # stops the arm, records, then goes on
        with pytest.raises(KeyboardInterrupt):
            executor(control).execute(validated, run)
        report = run.stages.execute
        assert report is not None and report.dry_run is False
    else:
        report = executor(control).execute(validated, run)
    assert not report.ok and report.message.startswith(expected)
    assert "stopped after 9 of" in report.message
    control.setWatchdog.assert_called_once_with(10.0)
    control.servoStop.assert_called_once()
    control.stopScript.assert_called_once()
    control.disconnect.assert_called_once()


def test_an_arm_that_does_not_follow_is_stopped(
    at_start: Any, validated: ValidatedTrajectory, tmp_path: Path
) -> None:
    control = fake_control(at_start)
    control.servoJ.side_effect = None  # the arm stays where moveJ left it
    control.servoJ.return_value = True
    report = executor(control, max_following_error=0.005).execute(
        validated, make_run(tmp_path, confirm=True)
    )
    assert not report.ok and "lags the command by" in report.message


@pytest.mark.parametrize("confirm", [False, True])
def test_no_arm_at_the_address_is_one_quick_clear_line_and_nothing_native_on_the_console(
    confirm: bool, validated: ValidatedTrajectory, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    from keymps_ur_rtde.executor import UrRtdeExecutor, UrRtdeOptions

    nobody = "127.0.0.2" if HOST != "127.0.0.2" else "127.0.0.3"
    started = time.perf_counter()
    report = UrRtdeExecutor(UrRtdeOptions(host=nobody)).execute(
        validated, make_run(tmp_path, confirm=confirm)
    )
    assert time.perf_counter() - started < 0.5
    assert not report.ok and report.dry_run is (not confirm)
    mode = "--confirm" if confirm else "dry run"
    assert report.message.startswith(f"executor ur-rtde ({mode}): cannot connect to the arm at")
    assert "connection refused" in report.message
    printed = capfd.readouterr()
    assert printed.out == "" and printed.err == ""


def test_the_native_librarys_prints_go_to_the_run_folder(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    import rtde_receive
    from keymps_ur_rtde.executor import native_output

    log = tmp_path / "ur_rtde.log"
    with native_output(log), pytest.raises(RuntimeError):
        # ur_rtde's C++ code itself prints "connect: Connection refused" on a closed port
        rtde_receive.RTDEReceiveInterface("127.0.0.2", 125.0, ["timestamp"])
    printed = capfd.readouterr()
    assert printed.out == "" and printed.err == ""
    assert "Connection refused" in log.read_text()
    print("the console is back")
    assert capfd.readouterr().out == "the console is back\n"


def test_dry_run_or_not_is_in_the_report_and_run_json(
    at_start: Any, validated: ValidatedTrajectory, tmp_path: Path
) -> None:
    from keymps.pipeline.run_folder import run_record

    run = make_run(tmp_path, confirm=False)
    run.stages.record("execute", executor().execute(validated, run))
    assert run.stages.execute is not None and run.stages.execute.dry_run is True
    assert run_record(run, None)["execution"]["dry_run"] is True
    confirmed = make_run(tmp_path / "c", confirm=True)
    report = executor(fake_control(at_start)).execute(validated, confirmed)
    confirmed.stages.record("execute", report)
    assert report.ok, report.message
    assert report.message.startswith("--confirm: executed")
    assert run_record(confirmed, None)["execution"]["dry_run"] is False


def test_the_approach_move_is_checked_like_the_trajectory(
    at_start: Any, validated: ValidatedTrajectory, tmp_path: Path
) -> None:
    # the arm's shoulder 0.6 rad down from the first sample: the moveJ from there would drive
    # the tool through the board; refused before the control interface is touched
    first = validated.trajectory.q[0]
    at_start.q[:] = list(first + np.array([0.0, 0.6, 0.0, 0.0, 0.0, 0.0]))
    time.sleep(0.02)
    report = executor(max_start_offset=1.0).execute(validated, make_run(tmp_path, confirm=True))
    assert not report.ok
    assert "refused before moving: safety: the move to the first sample:" in report.message
    assert "below the board" in report.message or "of the board surface" in report.message


def test_the_approach_check_passes_a_safe_start(
    at_start: Any, validated: ValidatedTrajectory, tmp_path: Path
) -> None:
    report = executor().execute(validated, make_run(tmp_path, confirm=False))
    assert report.ok and report.figures["approach_s"] > 0


@pytest.mark.parametrize("fault", ["frozen", "drop"])
def test_refuses_to_start_on_stale_or_lost_state(
    fault: str, at_start: Any, validated: ValidatedTrajectory, tmp_path: Path
) -> None:
    getattr(at_start, fault).value = 1
    try:
        time.sleep(0.05)
        report = executor().execute(validated, make_run(tmp_path, confirm=True))
    finally:
        getattr(at_start, fault).value = 0
    assert not report.ok
    assert (
        "does not update" in report.message
        or "disconnected" in report.message
        or ("cannot connect" in report.message or "lost the arm" in report.message)
    ), report.message


@pytest.mark.parametrize("fault", ["frozen", "drop"])
def test_stops_while_streaming_when_the_state_goes_stale_or_is_lost(
    fault: str, at_start: Any, validated: ValidatedTrajectory, tmp_path: Path
) -> None:
    control = fake_control(at_start)
    follow = control.servoJ.side_effect

    def servo(q: list[float], *args: Any) -> bool:
        if control.servoJ.call_count == 10:
            getattr(at_start, fault).value = 1
        return bool(follow(q, *args))

    control.servoJ.side_effect = servo
    try:
        report = executor(control).execute(validated, make_run(tmp_path, confirm=True))
    finally:
        getattr(at_start, fault).value = 0
    assert not report.ok, report.message
    expected = "stopped updating" if fault == "frozen" else "disconnected"
    assert expected in report.message, report.message
    # stale for 0.1 s at most: about 12 samples at 125 Hz after the fault, not the whole run
    assert control.servoJ.call_count < 10 + 30
    control.servoStop.assert_called_once()
    control.stopScript.assert_called_once()


def test_refuses_an_unvalidated_trajectory(validated: ValidatedTrajectory, tmp_path: Path) -> None:
    with pytest.raises(SafetyError, match="executor 'ur-rtde' refuses"):
        executor().execute(validated.trajectory, make_run(tmp_path, confirm=True))
    assert math.isfinite(validated.trajectory.duration_s)


@pytest.mark.parametrize(
    "host",
    [
        "10.0.0.1\n",
        "10.0.0.1 ",
        " ur3.lab",
        "10.0.0.1:30004",
        "ur3.lab\nrm -rf",
        "a\x00b",
        "-ur3.lab",
        "ur3..lab",
        "x" * 64 + ".lab",
        "",
    ],
)
def test_the_host_is_an_address_or_a_host_name_and_nothing_else(host: str) -> None:
    """A `$` in a pattern matches before a final newline: '10.0.0.1\\n' passed validation."""
    with pytest.raises(KeympsError, match="executor ur-rtde: option 'host': "):
        create_component("executor", "ur-rtde", {"host": host})


@pytest.mark.parametrize("host", ["192.168.1.10", "::1", "fe80::1", "ur3", "ur3-lab.example.org."])
def test_addresses_and_host_names_are_accepted(host: str) -> None:
    assert create_component("executor", "ur-rtde", {"host": host}).options.host == host
