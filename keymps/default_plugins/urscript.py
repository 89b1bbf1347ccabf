"""The `urscript` executor: writes the validated trajectory as a URScript program.

The program is one `def ... end` block, as the controller's script ports (30001-30003) want
it: a header of comments (task, keymps version, the trajectory's sha256), a slow movej to the
first sample, then either a servoj per sample at the trajectory's own timing or a movej per
joint-space waypoint, and stopj. It is only written: sending it is the user's step
(docs/exporters.md).
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from keymps._version import __version__
from keymps.errors import KeympsError
from keymps.plugin import (
    RegisterExecutor,
    RunFolderPath,
    hookimpl,
    parse_options,
    require_validated,
    trajectory_digest,
)
from keymps.types import ExecutionReport, Trajectory, ValidatedTrajectory

if TYPE_CHECKING:
    from keymps.robot.identity import ArmIdentity
    from keymps.run import Run

NAME = "urscript"
STOP_ACCELERATION = 2.0
"""stopj's deceleration, rad/s^2 (the trajectory ends at rest: it only ends servo mode)."""
CYCLE_TOLERANCE = 1e-9
"""How far (s) a servoj time may be from a whole number of controller cycles."""


class UrScriptOptions(BaseModel):
    """The executor section of a task file for `urscript` (every key but `name`)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True)

    file: RunFolderPath = Path("trajectory.script")
    """The program's file in the run folder (subfolders allowed)."""
    mode: Literal["servoj", "waypoints"] = "servoj"
    """servoj: every sample at its time; waypoints: a movej per joint-space waypoint."""
    lookahead_time: float = Field(0.1, ge=0.03, le=0.2)
    """servoj smoothing, s (the controller's range)."""
    gain: float = Field(300.0, ge=100, le=2000)
    """servoj proportional gain (the controller's range)."""
    approach_speed: float = Field(0.25, gt=0, le=1.0)
    """movej joint speed to the first sample, rad/s."""
    approach_acceleration: float = Field(0.5, gt=0, le=1.4)
    """movej joint acceleration to the first sample, rad/s^2."""
    waypoint_tolerance: float = Field(0.001, gt=0, le=0.05)
    """waypoints: the furthest any joint may stray from the trajectory between waypoints, rad."""


class UrScriptExecutor:
    """Writes a URScript program; moves nothing."""

    name = NAME

    def __init__(self, options: UrScriptOptions):
        self.options = options

    def execute(self, validated: ValidatedTrajectory, run: Run) -> ExecutionReport:
        from keymps.robot.identity import UNIVERSAL_ROBOTS, arm_identity
        from keymps.run_files import write_atomically

        trajectory = require_validated(validated, self.name)
        arm = arm_identity(run)
        if arm.maker != UNIVERSAL_ROBOTS:
            raise KeympsError(
                f"executor urscript: the run's arm is a {arm.maker} {arm.model}, and URScript "
                "runs only on Universal Robots controllers: choose another executor"
            )
        _check_joints(trajectory, arm)
        kept = None
        if self.options.mode == "waypoints":
            kept = waypoints(trajectory, self.options.waypoint_tolerance)
        program, figures = build_program(trajectory, arm, self.options, run.task.name, kept)
        if kept is not None:
            figures["max_waypoint_tool_deviation_mm"] = _tool_deviation_mm(run, trajectory, kept)
        target = run.path(str(self.options.file))
        try:
            write_atomically(target, program)
        except OSError as error:
            raise KeympsError(f"{target}: cannot write: {error.strerror}") from None
        return ExecutionReport(
            self.name,
            True,
            f"wrote {target} ({self.options.mode}, {int(figures['commands'])} motion commands, "
            f"{trajectory.duration_s:.2f} s on a {arm.model}); nothing was sent to an arm",
            (str(target),),
            figures,
        )


def _check_joints(trajectory: Trajectory, arm: ArmIdentity) -> None:
    if tuple(trajectory.joint_names) != arm.joint_names:
        raise KeympsError(
            f"executor urscript: the trajectory's joints ({', '.join(trajectory.joint_names)}) "
            f"are not the {arm.model}'s ({', '.join(arm.joint_names)})"
        )


def build_program(
    trajectory: Trajectory,
    arm: ArmIdentity,
    options: UrScriptOptions,
    task_name: str,
    kept: list[int] | None = None,
) -> tuple[str, dict[str, float]]:
    """The program's text (ASCII, one `def ... end`) and its figures (commands, seconds).

    Args:
        kept: for mode waypoints, the samples to move through (`waypoints`; computed if None).
    """
    q = np.asarray(trajectory.q, dtype=float)
    t = np.asarray(trajectory.t, dtype=float)
    label = _printable(task_name)
    figures = {"samples": float(len(t)), "duration_s": trajectory.duration_s}
    if options.mode == "servoj":
        body = _servoj_lines(q, t, arm, options)
    else:
        kept = kept if kept is not None else waypoints(trajectory, options.waypoint_tolerance)
        body = [
            f"  movej({_joints(q[i])}, t={t[i] - t[j]:.9f}, r=0)"
            for j, i in zip(kept[:-1], kept[1:], strict=True)
        ]
        figures["max_waypoint_deviation_rad"] = float(np.abs(q - between(q, t, kept)).max())
    figures["commands"] = float(len(body))
    lines = [
        f"def {_identifier(task_name)}():",
        *_header(trajectory, arm, options, label),
        f'  textmsg("keymps {label}: moving to the first sample")',
        f"  movej({_joints(q[0])}, a={options.approach_acceleration!r}, "
        f"v={options.approach_speed!r})",
        f'  textmsg("keymps {label}: {options.mode} {trajectory.duration_s:.3f} s")',
        *body,
        f"  stopj({STOP_ACCELERATION:g})",
        f'  textmsg("keymps {label}: done")',
        "end",
    ]
    return "\n".join(lines) + "\n", figures


def _header(
    trajectory: Trajectory, arm: ArmIdentity, options: UrScriptOptions, label: str
) -> list[str]:
    if options.mode == "servoj":
        how = (
            f"servoj every sample at its time (lookahead_time {options.lookahead_time:g} s, "
            f"gain {options.gain:g}), holding the last one for the lookahead time"
        )
    else:
        how = f"movej per waypoint (within {options.waypoint_tolerance:g} rad), at rest at each"
    return [
        f"  # keymps {__version__} URScript program",
        f"  # task: {label}",
        f"  # trajectory sha256: {trajectory_digest(trajectory)}",
        f"  # arm: {arm.model} ({arm.generation}, controller {arm.controller_hz:g} Hz); joints "
        "in the controller's order, radians",
        f"  # {trajectory.samples} samples at {trajectory.rate_hz:g} Hz, "
        f"{trajectory.duration_s:.3f} s",
        f"  # approach: movej to the first sample at {options.approach_speed:g} rad/s, "
        f"{options.approach_acceleration:g} rad/s^2",
        f"  # motion: {how}; stopj({STOP_ACCELERATION:g}) at the end",
    ]


def _servoj_lines(
    q: np.ndarray, t: np.ndarray, arm: ArmIdentity, options: UrScriptOptions
) -> list[str]:
    """One servoj per sample after the first (whose time is the time since the one before),
    and one holding the last sample for the lookahead time (rounded up to whole cycles)."""
    cycle = 1.0 / arm.controller_hz
    steps = np.diff(t)
    cycles = steps / cycle
    bad = np.flatnonzero(
        (steps <= 0) | (np.abs(cycles - np.round(cycles)) * cycle > CYCLE_TOLERANCE)
    )
    if len(bad):
        i = int(bad[0])
        raise KeympsError(
            f"executor urscript: samples {i} and {i + 1} are {steps[i]:.6f} s apart, not a whole "
            f"number of the {arm.model} controller's {cycle:g} s cycles: set robot.rate_hz to "
            f"{arm.controller_hz:g} (or a divisor of it) or use mode: waypoints"
        )
    servo = f"lookahead_time={options.lookahead_time!r}, gain={options.gain!r}"
    lines = [
        f"  servoj({_joints(q[i + 1])}, 0, 0, t={step:.9f}, {servo})"
        for i, step in enumerate(steps.tolist())
    ]
    if len(q) > 1:
        hold = math.ceil(options.lookahead_time / cycle - CYCLE_TOLERANCE) * cycle
        lines.append(f"  servoj({_joints(q[-1])}, 0, 0, t={hold:.9f}, {servo})")
    return lines


def waypoints(trajectory: Trajectory, tolerance: float) -> list[int]:
    """The samples to move through (indices, first and last included, every piece's end kept)
    so that moving straight in joint space between them strays at most `tolerance` rad from
    every sample in between, judged at the sample's time (Douglas-Peucker in joint space)."""
    q, t = np.asarray(trajectory.q, dtype=float), np.asarray(trajectory.t, dtype=float)
    ends = np.flatnonzero(np.diff(np.asarray(trajectory.piece_index)) != 0)
    keep = {0, len(q) - 1, *ends.tolist()}
    order = sorted(keep)
    spans = list(zip(order[:-1], order[1:], strict=True))
    while spans:
        a, b = spans.pop()
        if b - a < 2:
            continue
        inner = np.arange(a + 1, b)
        straight = between(q[[a, b]], t[[a, b]], [0, 1], t[inner])
        error = np.abs(q[inner] - straight).max(axis=1)
        worst = int(np.argmax(error))
        if error[worst] > tolerance:
            middle = int(inner[worst])
            keep.add(middle)
            spans += [(a, middle), (middle, b)]
    return sorted(keep)


def between(
    q: np.ndarray, t: np.ndarray, kept: list[int], at: np.ndarray | None = None
) -> np.ndarray:
    """(m, 6) the joints of straight joint-space moves through the samples `kept`, at the
    times `at` (default: every sample's time t)."""
    times = t if at is None else at
    return np.column_stack([np.interp(times, t[kept], q[kept, j]) for j in range(q.shape[1])])


def _tool_deviation_mm(run: Run, trajectory: Trajectory, kept: list[int]) -> float:
    """How far (mm) the tool tip of the waypoint moves strays from the trajectory's at the
    sample times."""
    from keymps.robot.identity import tool_poses

    q, t = np.asarray(trajectory.q, dtype=float), np.asarray(trajectory.t, dtype=float)
    line, _ = tool_poses(run, between(q, t, kept))
    planned, _ = tool_poses(run, q)
    return float(1000.0 * np.linalg.norm(line - planned, axis=1).max())


def _joints(q: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.9f}" for v in q.tolist()) + "]"


def _printable(text: str) -> str:
    """`text` for a comment or textmsg: ASCII letters, digits and ` _.-` only (a task name
    comes from the task file: it must not end the comment or the string)."""
    return re.sub(r"[^A-Za-z0-9 _.\-]", "?", text)[:80]


def _identifier(task_name: str) -> str:
    words = re.sub(r"[^a-z0-9]+", "_", task_name.lower()).strip("_")[:40]
    return f"keymps_{words}" if words else "keymps_program"


def make_urscript_executor(options: dict[str, Any]) -> UrScriptExecutor:
    return UrScriptExecutor(parse_options(UrScriptOptions, options, "executor urscript"))


@hookimpl
def register_executors(register: RegisterExecutor) -> None:
    register(NAME, make_urscript_executor)
