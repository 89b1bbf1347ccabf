"""The `ur-rtde` executor: streams a validated keymps trajectory to a real UR arm over RTDE.

Sequence: connect the receive interface, check that it is connected and its timestamp
advances, that the arm is powered, running and in normal safety mode, that the trajectory starts
near the arm's current joints, and that the moveJ from there to the first sample passes the
same safety check as the trajectory; then (only with --confirm) connect the control interface,
moveJ slowly to the first point, and stream every sample with servoJ at the controller rate,
watching the receive interface, the safety mode and the following error at every sample. Any
error, safety stop, stale state or stop signal (Ctrl-C, SIGTERM, SIGHUP) stops the arm
(servoStop, stopScript) and disconnects; a signal then goes on, so that run.json records the run
as interrupted, with how far the arm got. The controller's RTDE watchdog stops the arm when
keymps is killed outright (kill -9): it expects a command from keymps at least `watchdog_hz`
times a second. Without --confirm it is a dry run: the checks run, nothing moves. What ur_rtde's
C++ code prints itself goes to ur_rtde.log in the run folder, not to the console.
"""

from __future__ import annotations

import contextlib
import ipaddress
import math
import os
import re
import socket
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from keymps.errors import KeympsError
from keymps.plugin import interrupt_name, interrupts_deferred, parse_options, require_validated
from keymps.types import ExecutionReport
from keymps_ur_rtde import NAME

ROBOT_MODES = {
    -1: "NO_CONTROLLER",
    0: "DISCONNECTED",
    1: "CONFIRM_SAFETY",
    2: "BOOTING",
    3: "POWER_OFF",
    4: "POWER_ON",
    5: "IDLE",
    6: "BACKDRIVE",
    7: "RUNNING",
    8: "UPDATING_FIRMWARE",
}
SAFETY_MODES = {
    1: "NORMAL",
    2: "REDUCED",
    3: "PROTECTIVE_STOP",
    4: "RECOVERY",
    5: "SAFEGUARD_STOP",
    6: "SYSTEM_EMERGENCY_STOP",
    7: "ROBOT_EMERGENCY_STOP",
    8: "VIOLATION",
    9: "FAULT",
    10: "VALIDATE_JOINT_ID",
    11: "UNDEFINED_SAFETY_MODE",
    12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
    13: "SYSTEM_THREE_POSITION_ENABLING_STOP",
}
RUNNING = 7
SAFE_MODES = {1, 2}  # NORMAL and REDUCED allow motion
RECEIVE_VARIABLES = ["timestamp", "actual_q", "robot_mode", "safety_mode", "runtime_state"]
RTDE_PORT = 30004
CONNECT_TIMEOUT_S = 2.0
"""How long the TCP probe of the RTDE port waits for an arm that does not answer."""
STALE_S = 0.1
"""The receive interface's timestamp must advance at least this often (12 periods at 125 Hz)."""
LOG_NAME = "ur_rtde.log"


class UrRtdeOptions(BaseModel):
    """The executor section of a task file for `ur-rtde` (every key but `name`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    host: str = Field(min_length=1, description="the arm's IP address")
    """The arm's IP address or host name (RTDE port 30004, script ports 30001-30003)."""
    lookahead_time: float = Field(0.1, ge=0.03, le=0.2)
    """servoJ smoothing, seconds (ur_rtde's range)."""
    gain: float = Field(300.0, ge=100, le=2000)
    """servoJ proportional gain (ur_rtde's range)."""
    approach_speed: float = Field(0.25, gt=0, le=1.0)
    """moveJ joint speed to the first point, rad/s."""
    approach_acceleration: float = Field(0.5, gt=0, le=1.4)
    """moveJ joint acceleration to the first point, rad/s^2."""
    max_start_offset: float = Field(0.35, gt=0, le=1.5)
    """Refuse when any joint is further than this from the first point, rad."""
    max_following_error: float = Field(0.2, gt=0, le=1.0)
    """Stop when any joint lags the command by more than this while streaming, rad."""
    watchdog_hz: float = Field(10.0, ge=1.0, le=125.0)
    """The controller stops the arm when keymps sends it nothing for 1/watchdog_hz s (keymps
    killed, frozen or cut off), Hz."""

    @field_validator("host")
    @classmethod
    def _an_address(cls, host: str) -> str:
        if not is_host(host):
            raise ValueError(
                f"{host!r} is not an IP address or a host name (letters, digits, '-' and '.')"
            )
        return host


HOST_LABEL = re.compile(r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?")
"""One dot-separated label of a host name (RFC 1123), matched whole."""


def is_host(text: str) -> bool:
    """Whether `text` is an IPv4 or IPv6 address or a host name, and nothing else (a newline,
    a space or a port would otherwise reach ur_rtde's connect call)."""
    try:
        ipaddress.ip_address(text)
        return True
    except ValueError:
        pass
    labels = text.removesuffix(".").split(".")
    return len(text) <= 253 and all(HOST_LABEL.fullmatch(label) for label in labels)


def _connect_receive(host: str, frequency: float) -> Any:
    import rtde_receive

    _probe(host, RTDE_PORT)
    return rtde_receive.RTDEReceiveInterface(host, frequency, RECEIVE_VARIABLES)


def _probe(host: str, port: int) -> None:
    """Fail fast, in words, when nothing answers on host:port (before ur_rtde tries)."""
    try:
        with socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S):
            pass
    except ConnectionRefusedError:
        raise KeympsError(
            f"executor ur-rtde: cannot connect to the arm at {host} (RTDE port {port}): "
            "connection refused; is the arm (or URSim) on and is executor.host its address?"
        ) from None
    except TimeoutError:
        raise KeympsError(
            f"executor ur-rtde: no answer from {host} (RTDE port {port}) within "
            f"{CONNECT_TIMEOUT_S:g} s; check the network and executor.host"
        ) from None
    except OSError as error:
        raise KeympsError(
            f"executor ur-rtde: cannot connect to the arm at {host} (RTDE port {port}): "
            f"{error.strerror or error}"
        ) from None


@contextlib.contextmanager
def native_output(log: Path) -> Iterator[None]:
    """File descriptors 1 and 2 go to `log` meanwhile: ur_rtde's C++ code prints there
    ("connect: Connection refused") instead of on the console."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    saved = []
    try:
        with open(log, "ab") as sink:
            for fd in (1, 2):
                saved.append((fd, os.dup(fd)))
                os.dup2(sink.fileno(), fd)
            try:
                yield
            finally:
                for stream in (sys.stdout, sys.stderr):
                    with contextlib.suppress(Exception):
                        stream.flush()
                for fd, copy in saved:
                    os.dup2(copy, fd)
                    os.close(copy)
                saved.clear()
    finally:
        for fd, copy in saved:  # the log could not be opened half-way: restore what moved
            os.dup2(copy, fd)
            os.close(copy)


def _connect_control(host: str, frequency: float) -> Any:
    import rtde_control

    return rtde_control.RTDEControlInterface(host, frequency)


class StreamStopped(Exception):
    """Streaming ended early; the message says why."""


class UrRtdeExecutor:
    """Runs a validated trajectory on a UR arm; a dry run unless run.options.confirm."""

    name = NAME

    def __init__(
        self,
        options: UrRtdeOptions,
        connect_receive: Callable[[str, float], Any] = _connect_receive,
        connect_control: Callable[[str, float], Any] = _connect_control,
    ):
        self.options = options
        self.samples_sent = 0
        self.stopped: ExecutionReport | None = None
        """The report of a run a stop signal ended (recorded before the signal goes on)."""
        self.connect_receive = connect_receive
        self.connect_control = connect_control

    def execute(self, validated: Any, run: Any) -> ExecutionReport:

        trajectory = require_validated(validated, self.name)
        confirm = bool(getattr(run.options, "confirm", False))
        mode = "--confirm" if confirm else "dry run"
        log = run.path(LOG_NAME)
        self.stopped = None
        try:
            with native_output(log):
                report = self._checked_execute(trajectory, run, confirm)
        except KeympsError as error:
            message = str(error).replace(f"executor {NAME}: ", f"executor {NAME} ({mode}): ", 1)
            report = ExecutionReport(self.name, False, message)
        except KeyboardInterrupt as interrupt:  # the arm is stopped: run.json says how far it
            stopped = self.stopped or ExecutionReport(  # got, and the run ends as interrupted
                self.name, False, f"stopped by {interrupt_name(interrupt)}; nothing moved"
            )
            run.stages.record("execute", _with_log(stopped, log, confirm))
            raise
        return _with_log(report, log, confirm)

    def _checked_execute(self, trajectory: Any, run: Any, confirm: bool) -> ExecutionReport:
        rate = float(trajectory.rate_hz)
        host = self.options.host
        try:
            receive = self.connect_receive(host, rate)
        except KeympsError:
            raise
        except Exception as error:  # ur_rtde raises RuntimeError or boost errors
            raise KeympsError(
                f"executor ur-rtde: cannot connect to the arm at {host} (RTDE port 30004): {error}"
            ) from None
        try:
            try:
                offset = self._preflight(receive, trajectory)
                approach = self._check_approach(receive, trajectory, run)
            except KeympsError:
                raise
            except Exception as error:  # the receive interface failed; nothing has moved
                raise KeympsError(
                    f"executor ur-rtde: lost the arm at {host} before moving: {error}"
                ) from None
            figures = {
                "duration_s": trajectory.duration_s,
                "samples": float(trajectory.samples),
                "start_offset_rad": offset,
                "approach_s": approach,
            }
            if not confirm:
                return ExecutionReport(
                    self.name,
                    True,
                    f"dry run: {host} is RUNNING in NORMAL safety mode and the trajectory starts "
                    f"{offset:.3f} rad from the arm's joints; nothing moved. Run again with "
                    "--confirm to move the arm.",
                    (),
                    figures,
                )
            return self._move(receive, trajectory, figures)
        finally:
            _quietly(receive.disconnect)

    def _check_approach(self, receive: Any, trajectory: Any, run: Any) -> float:
        """The moveJ to the first sample, checked by keymps' safety validator; its seconds."""
        from keymps.plugin import SafetyError
        from keymps.robot.approach import check_approach
        from keymps.robot.model import RobotModel

        options = self.options
        actual = np.asarray(receive.getActualQ(), dtype=float)
        try:
            report = check_approach(
                RobotModel.from_task(run.task),
                actual,
                np.asarray(trajectory.q[0], dtype=float),
                run.task,
                speed=options.approach_speed,
                acceleration=options.approach_acceleration,
                rate_hz=float(trajectory.rate_hz),
            )
        except SafetyError as error:
            raise KeympsError(
                f"executor ur-rtde: refused before moving: {error}; jog the arm to "
                f"[{', '.join(f'{v:.3f}' for v in trajectory.q[0])}] rad first"
            ) from None
        return float(report.figures["duration_s"])

    def _preflight(self, receive: Any, trajectory: Any) -> float:
        """Refuse unless the state is live, the arm running, safe, and near the first point."""
        host = self.options.host
        self._fresh = _Freshness(receive)
        problem = self._fresh.wait_for_news()
        if problem:
            raise KeympsError(f"executor ur-rtde: the arm at {host}: {problem}; nothing moved")
        mode = int(receive.getRobotMode())
        if mode != RUNNING:
            raise KeympsError(
                f"executor ur-rtde: the arm at {host} is {ROBOT_MODES.get(mode, mode)}, not "
                "RUNNING: power it on and release the brakes on the teach pendant"
            )
        safety = int(receive.getSafetyMode())
        if safety not in SAFE_MODES:
            raise KeympsError(
                f"executor ur-rtde: the arm at {host} is in safety mode "
                f"{SAFETY_MODES.get(safety, safety)}: clear it on the teach pendant first"
            )
        actual = np.asarray(receive.getActualQ(), dtype=float)
        first = np.asarray(trajectory.q[0], dtype=float)
        if actual.shape != (6,):
            raise KeympsError(f"executor ur-rtde: the arm reported {actual.shape} joint values")
        offsets = np.abs(first - actual)
        worst = int(np.argmax(offsets))
        if offsets[worst] > self.options.max_start_offset:
            raise KeympsError(
                f"executor ur-rtde: the trajectory starts {offsets[worst]:.2f} rad away from the "
                f"arm's {trajectory.joint_names[worst]} (at most "
                f"{self.options.max_start_offset:.2f}); jog the arm to "
                f"[{', '.join(f'{v:.3f}' for v in first)}] rad first"
            )
        return float(offsets.max())

    def _move(self, receive: Any, trajectory: Any, figures: dict[str, float]) -> ExecutionReport:
        options = self.options
        rate = float(trajectory.rate_hz)
        try:
            control = self.connect_control(options.host, rate)
        except Exception as error:
            raise KeympsError(
                f"executor ur-rtde: cannot take control of the arm at {options.host} (is it in "
                f"remote control mode?): {error}"
            ) from None
        started = time.monotonic()
        self.samples_sent = 0
        try:
            if not control.setWatchdog(options.watchdog_hz):
                raise StreamStopped("the controller refused to set the RTDE watchdog")
            self._approach(control, receive, trajectory, figures["start_offset_rad"])
            self._stream(control, receive, trajectory)
        except KeyboardInterrupt as interrupt:
            why = f"stopped by {interrupt_name(interrupt)}"
            self.stopped = self._stopped(control, trajectory, why, figures)
            raise
        except StreamStopped as reason:
            return self._stopped(control, trajectory, str(reason), figures)
        except Exception as error:  # anything from ur_rtde: stop first, then report
            return self._stopped(control, trajectory, f"error: {error}", figures)
        except BaseException:  # SystemExit from a signal handler, GeneratorExit ...: stop, re-raise
            _stop(control)
            raise
        sent = self.samples_sent
        _stop(control)
        figures["wall_time_s"] = time.monotonic() - started
        figures["samples_sent"] = float(sent)
        return ExecutionReport(
            self.name,
            True,
            f"--confirm: executed {trajectory.duration_s:.1f} s ({sent} samples at {rate:g} Hz) "
            f"on {options.host}",
            (),
            figures,
        )

    def _approach(self, control: Any, receive: Any, trajectory: Any, offset: float) -> None:
        """moveJ (asynchronous, so safety and Ctrl-C are watched) to the first sample."""
        options = self.options
        first = [float(v) for v in trajectory.q[0]]
        if not control.moveJ(first, options.approach_speed, options.approach_acceleration, True):
            raise StreamStopped("moveJ to the first point was refused")
        expected = offset / options.approach_speed + options.approach_speed / (
            options.approach_acceleration
        )
        deadline = time.monotonic() + 2.0 * expected + 2.0
        while control.getAsyncOperationProgress() >= 0:
            control.kickWatchdog()
            self._check_safety(receive, "during the move to the first point")
            if time.monotonic() > deadline:
                _quietly(lambda: control.stopJ(options.approach_acceleration))
                raise StreamStopped("the move to the first point did not finish in time")
            time.sleep(0.01)
        actual = np.asarray(receive.getActualQ(), dtype=float)
        miss = float(np.abs(actual - np.asarray(first)).max())
        if miss > 0.01:
            raise StreamStopped(f"the arm stopped {miss:.3f} rad short of the first point")

    def _stream(self, control: Any, receive: Any, trajectory: Any) -> None:
        """servoJ every sample at the controller rate (counted in self.samples_sent)."""
        options = self.options
        period = 1.0 / float(trajectory.rate_hz)
        commands = np.asarray(trajectory.q, dtype=float)
        window = math.ceil((options.lookahead_time + 0.2) / period)
        for index, q in enumerate(commands):
            cycle = control.initPeriod()
            if not control.servoJ(
                [float(v) for v in q], 0.0, 0.0, period, options.lookahead_time, options.gain
            ):
                raise StreamStopped(f"servoJ refused sample {index}")
            self.samples_sent = index + 1
            self._check_safety(receive, f"at t={index * period:.3f} s")
            # servoJ smooths over its lookahead: compare with the recent commands, not the last
            actual = np.asarray(receive.getActualQ(), dtype=float)
            recent = commands[max(0, index - window) : index + 1]
            lag = float(np.abs(recent - actual).max(axis=1).min())
            if lag > options.max_following_error:
                raise StreamStopped(
                    f"the arm lags the command by {lag:.3f} rad at t={index * period:.3f} s"
                )
            control.waitPeriod(cycle)

    def _check_safety(self, receive: Any, when: str) -> None:
        problem = self._fresh.problem()
        if problem:
            raise StreamStopped(f"{problem} {when}")
        safety = int(receive.getSafetyMode())
        if safety not in SAFE_MODES:
            raise StreamStopped(f"safety mode {SAFETY_MODES.get(safety, safety)} {when}")
        mode = int(receive.getRobotMode())
        if mode != RUNNING:
            raise StreamStopped(f"robot mode {ROBOT_MODES.get(mode, mode)} {when}")

    def _stopped(
        self, control: Any, trajectory: Any, why: str, figures: dict[str, float]
    ) -> ExecutionReport:
        _stop(control)
        sent = self.samples_sent
        period = 1.0 / float(trajectory.rate_hz)
        figures["samples_sent"] = float(sent)
        return ExecutionReport(
            self.name,
            False,
            f"{why}; the arm was stopped after {sent} of {trajectory.samples} samples "
            f"(t={sent * period:.3f} s)",
            (),
            figures,
        )


class _Freshness:
    """Whether the receive interface is connected and its state still new (timestamp moving)."""

    def __init__(self, receive: Any):
        self.receive = receive
        self.last = float(receive.getTimestamp())
        self.changed = time.monotonic()

    def problem(self) -> str | None:
        if not self.receive.isConnected():
            return "the RTDE receive interface is disconnected"
        now = float(self.receive.getTimestamp())
        if now != self.last:
            self.last, self.changed = now, time.monotonic()
        elif time.monotonic() - self.changed > STALE_S:
            return (
                f"the arm's state stopped updating (timestamp {now:.3f} s for over {STALE_S:g} s)"
            )
        return None

    def wait_for_news(self) -> str | None:
        """None as soon as the timestamp advances; else why not, after STALE_S at most."""
        first = self.last
        deadline = time.monotonic() + STALE_S
        while time.monotonic() < deadline:
            if not self.receive.isConnected():
                return "the RTDE receive interface is disconnected"
            if float(self.receive.getTimestamp()) != first:
                self.problem()  # records the new timestamp
                return None
            time.sleep(0.002)
        return f"the arm's state does not update (timestamp stuck at {first:.3f} s)"


def _stop(control: Any) -> None:
    """Stop servoing, stop the control script, disconnect; never raise while stopping, and a
    second Ctrl-C or SIGTERM waits until the arm is stopped."""
    with interrupts_deferred():
        _quietly(control.servoStop)
        _quietly(control.stopScript)
        _quietly(control.disconnect)


def _with_log(report: ExecutionReport, log: Path, confirm: bool) -> ExecutionReport:
    """The report with ur_rtde.log among its files (removed when empty) and dry run or not."""
    files = (str(log),) if log.is_file() and log.stat().st_size else ()
    if not files:
        log.unlink(missing_ok=True)
    return replace(report, files=report.files + files, dry_run=not confirm)


def _quietly(action: Callable[[], Any]) -> None:
    # the arm may already be gone; stopping must not fail
    with contextlib.suppress(Exception):
        action()


def make_executor(options: dict[str, Any]) -> UrRtdeExecutor:
    return UrRtdeExecutor(parse_options(UrRtdeOptions, options, "executor ur-rtde"))
