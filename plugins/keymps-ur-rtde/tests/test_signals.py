"""`keymps run --confirm` on the fake controller, ended by a signal: real processes throughout.

keymps runs as its own process with the real ur_rtde receive and control interfaces, which talk
RTDE, the dashboard and the script port to the fake controller (fake_rtde_server.py, another
process) on a 127.0.1.x address. Each test waits for a marker, never for a time: the
controller's count of servoJ commands says the arm is moving before the signal is sent.
"""

from __future__ import annotations

import csv
import json
import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import fake_rtde_server
import pytest

REPO = Path(__file__).resolve().parents[3]
HOST = f"127.0.1.{random.randint(20, 250)}"
KEYMPS = [sys.executable, "-c", "from keymps.cli.app import main; main()"]
MOVING = 100
"""servoJ commands the controller has seen when the test signals keymps (0.8 s of streaming)."""


@pytest.fixture(scope="module")
def arm() -> Iterator[fake_rtde_server.ArmState]:
    state = fake_rtde_server.ArmState([0.0] * 6)
    process = fake_rtde_server.start(HOST, state)
    yield state
    process.terminate()
    process.join(5)


@pytest.fixture(scope="module")
def task(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The paper's pizza cut (42 s of streaming) on the fake controller."""
    folder = tmp_path_factory.mktemp("task")
    text = (REPO / "tasks/object_cutting.yaml").read_text()
    text = text.replace("scenes/pizza.png", str(REPO / "tasks/scenes/pizza.png"))
    text = text.replace("prompt: ../prompts/", f"prompt: {REPO}/prompts/")
    text = text.replace(
        "executor: {name: sim}", f"executor: {{name: ur-rtde, host: {HOST}, watchdog_hz: 4}}"
    )
    (folder / "task.yaml").write_text(text)
    return folder / "task.yaml"


@pytest.fixture(scope="module")
def first_sample(task: Path, tmp_path_factory: pytest.TempPathFactory) -> list[float]:
    """The trajectory's first joints (a dry run writes trajectory.csv, then refuses: the arm
    is elsewhere)."""
    out = tmp_path_factory.mktemp("dry") / "run"
    _keymps(task, out).communicate(timeout=120)
    with (out / "trajectory.csv").open() as handle:
        first = next(csv.DictReader(handle))
    return [float(first[f"q{i}"]) for i in range(1, 7)]


@pytest.fixture
def at_the_start(arm: fake_rtde_server.ArmState, first_sample: list[float]) -> None:
    """The fake arm on the trajectory's first sample."""
    arm.q[:] = first_sample


def _keymps(task: Path, out: Path, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [*KEYMPS, "run", str(task), "--backend", "offline", "--rerun", "off", "--out", str(out)]
        + list(extra),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for(condition: Callable[[], bool], what: str, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


def _moving_run(arm: fake_rtde_server.ArmState, task: Path, out: Path) -> subprocess.Popen[str]:
    """keymps run --confirm, returned once the arm has taken MOVING servoJ commands."""
    before = arm.servo_commands.value
    process = _keymps(task, out, "--confirm")
    _wait_for(
        lambda: arm.servo_commands.value >= before + MOVING or process.poll() is not None,
        "the arm to move",
    )
    assert process.poll() is None, process.communicate()[1][-3000:]
    return process


@pytest.mark.parametrize(
    ("signum", "code", "name"),
    [(signal.SIGTERM, 143, "SIGTERM"), (signal.SIGHUP, 129, "SIGHUP"), (signal.SIGINT, 130, "")],
)
def test_a_signal_stops_the_arm_and_records_where(
    signum: int,
    code: int,
    name: str,
    arm: fake_rtde_server.ArmState,
    task: Path,
    at_the_start: None,
    tmp_path: Path,
) -> None:
    """Was: SIGTERM or SIGHUP killed keymps at once (no servoStop, stopScript or disconnect,
    no run.json), and Ctrl-C recorded a failed run with exit code 1."""
    stops = (arm.servo_stops.value, arm.script_stops.value, arm.control_disconnects.value)
    process = _moving_run(arm, task, tmp_path / "run")
    process.send_signal(signum)
    _, stderr = process.communicate(timeout=60)
    after = (arm.servo_stops.value, arm.script_stops.value, arm.control_disconnects.value)
    assert [b - a for a, b in zip(stops, after, strict=True)] == [1, 1, 1], arm.counts()
    assert process.returncode == code, stderr[-3000:]
    who = name or "Ctrl-C"
    assert stderr.strip().splitlines()[-1] == f"error: interrupted ({who})", stderr[-3000:]
    assert "Traceback" not in stderr
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["status"] == "interrupted", record["error"]
    by = name or "the user (Ctrl-C)"
    assert record["error"] == f"interrupted by {by} during stage 'execute'; nothing after it ran"
    execution = record["execution"]
    assert execution["dry_run"] is False and execution["ok"] is False
    assert execution["message"].startswith(f"stopped by {who}; the arm was stopped after ")
    assert execution["figures"]["samples_sent"] >= MOVING
    sent = arm.servo_commands.value
    time.sleep(0.3)
    assert arm.servo_commands.value == sent and not arm.program_running.value


def test_kill_9_the_watchdog_stops_the_arm(
    arm: fake_rtde_server.ArmState, task: Path, at_the_start: None, tmp_path: Path
) -> None:
    """Was: no watchdog was set; the controller's program ran on after keymps died."""
    trips = arm.watchdog_trips.value
    process = _moving_run(arm, task, tmp_path / "run")
    assert arm.watchdog_hz.value == 4.0 and arm.watchdog_updates.value >= MOVING
    os.kill(process.pid, signal.SIGKILL)
    process.communicate(timeout=60)
    _wait_for(lambda: arm.watchdog_trips.value > trips, "the watchdog to stop the arm", 10.0)
    assert not arm.program_running.value
    sent = arm.servo_commands.value
    time.sleep(0.3)
    assert arm.servo_commands.value == sent
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["status"] == "unfinished" and "a real arm may have moved" in record["error"]
