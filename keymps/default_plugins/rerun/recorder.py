"""Records every stage of every run in Rerun: one recording per run (see docs/rerun.md).

run.options.rerun chooses the sink: "save" (run.rrd in the run folder, the default), "spawn"
(a new viewer), "connect" (a running viewer at run.options.rerun_url) or "off" (nothing).

"save" records into memory and writes run.rrd once, atomically, when the run ends: Rerun's own
file sink hung the run on a full disk (in `save`, `flush` or `disconnect`), and left a cut file.
"""

from __future__ import annotations

import os
import re
import sys
import threading
import uuid
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from keymps.errors import KeympsError, os_error_message
from keymps.plugin import hookimpl
from keymps.run import Run
from keymps.run_files import write_atomically
from keymps.types import STAGES

APPLICATION_ID = "keymps"
RECORDING_FILE = "run.rrd"
MODES = ("save", "spawn", "connect", "off")
MIN_RERUN_VERSION = (0, 41)
"""Oldest rerun-sdk tested (named transform frames, rerun.urdf, rerun.chunk.RrdReader)."""
FLUSH_TIMEOUT_S = 30.0
"""Longest wait for the recording to reach its file or viewer when a run ends."""
DISCONNECT_TIMEOUT_S = 5.0
"""Longest wait for a viewer connection to close after the flush (a viewer that is gone)."""
ROBOT_RATE_HZ = 25.0
"""The animated robot and tool tip are subsampled to this rate; joint series keep every sample."""
STAGE_ORDER: tuple[str, ...] = (*STAGES, "finished")
"""Position on the `stage` timeline."""


@dataclass
class _Session:
    """One run's recording: its stream, mode and where it goes."""

    stream: Any
    """rerun.RecordingStream of this run (never the global one)."""
    mode: str
    memory: Any = None
    """"save": the rerun.BinaryStream the recording goes to, written to `target` at the end."""
    target: Path | None = None


_sessions: dict[int, _Session | None] = {}
"""id(run) -> its recording; None when recording failed to start (not retried)."""


def stage_index(stage: str) -> int:
    """The step of a stage on the `stage` timeline (unknown stages after the known ones)."""
    return STAGE_ORDER.index(stage) if stage in STAGE_ORDER else len(STAGE_ORDER)


def eye_position(run: Run) -> tuple[list[float], list[float]]:
    """(eye, target): above the board, on the side away from the robot, a little aside."""
    import numpy as np

    from keymps.default_plugins.rerun.entities import board_rectangle

    low, high = board_rectangle(run)
    center = (low + high) / 2.0
    base = run.robot.base[:2] if run.robot is not None else None
    away = center - np.array(base or run.task.robot.base_xy(run.task.scene.workspace), dtype=float)
    norm = float(np.linalg.norm(away))
    away = away / norm if norm > 1e-6 else np.array([0.0, 1.0])
    side = np.array([-away[1], away[0]])
    eye = center + 0.5 * away + 0.2 * side
    return [float(eye[0]), float(eye[1]), 0.45], [float(center[0]), float(center[1]), 0.05]


def blueprint(run: Run) -> Any:
    """3D scene left; image with overlays and the VLM exchange middle; joint curves right."""
    import rerun.blueprint as rrb

    eye, target = eye_position(run)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(
                name="3D scene",
                origin="world",
                eye_controls=rrb.EyeControls3D(
                    position=eye, look_target=target, eye_up=[0.0, 0.0, 1.0]
                ),
            ),
            rrb.Vertical(
                rrb.Spatial2DView(name="Image and plan", origin="image"),
                rrb.Tabs(
                    rrb.TextDocumentView(name="VLM answer", origin="vlm/answer"),
                    rrb.TextDocumentView(name="VLM prompt", origin="vlm/prompt"),
                    rrb.TextDocumentView(name="VLM attempts", origin="vlm/attempts"),
                    rrb.Spatial2DView(name="Crop", origin="crop"),
                    rrb.Spatial2DView(name="Execution video", origin="execution/video"),
                    rrb.TextDocumentView(name="Safety check", origin="check/report"),
                    rrb.TextDocumentView(name="Run", origin="run/summary"),
                ),
                row_shares=[3, 2],
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(name="Joint positions [rad]", origin="joints/q"),
                rrb.TimeSeriesView(name="Joint velocities [rad/s]", origin="joints/qd"),
                rrb.TimeSeriesView(name="Tool speed [m/s]", origin="tool"),
            ),
            column_shares=[5, 4, 3],
        ),
        rrb.TimePanel(timeline="time", state="expanded"),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )


def _check_version(version: str) -> None:
    numbers = tuple(int(part) for part in re.findall(r"\d+", version)[:2])
    if numbers < MIN_RERUN_VERSION:
        wanted = ".".join(map(str, MIN_RERUN_VERSION))
        raise KeympsError(
            f"the Rerun recorder needs rerun-sdk >= {wanted}, found {version}: "
            f"pip install 'rerun-sdk>={wanted}' (or run with --rerun off)"
        )


def has_display() -> bool:
    """False where no viewer window can open (Linux without X11 or Wayland, e.g. over SSH)."""
    if not sys.platform.startswith("linux"):
        return True
    return any(os.environ.get(name) for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"))


def _open(run: Run) -> _Session:
    import rerun as rr

    mode = run.options.rerun
    if mode not in MODES:
        raise KeympsError(f"--rerun: unknown mode {mode!r} (choose one of {', '.join(MODES)})")
    _check_version(rr.__version__)
    if mode == "spawn" and not has_display():
        # Spawning would wait for a viewer that cannot start, then stream to nothing.
        mode = "save"
        run.warnings.append(
            f"--rerun spawn: no display to open a viewer on (DISPLAY is not set); saved "
            f"{run.folder / RECORDING_FILE} instead"
        )
    stream = rr.RecordingStream(
        APPLICATION_ID,
        recording_id=uuid.uuid4(),
        send_properties=False,  # the default properties carry a wall-clock start time
    )
    stream.set_log_time_enabled(False)
    stream.set_log_tick_enabled(False)
    layout = blueprint(run)
    memory = None
    try:
        if mode == "save":
            memory = rr.binary_stream(recording=stream)
            stream.send_blueprint(layout, make_active=True, make_default=True)
        elif mode == "spawn":
            stream.spawn(default_blueprint=layout)
        else:
            if not run.options.rerun_url:
                raise KeympsError(
                    "--rerun connect needs a viewer URL, e.g. rerun+http://127.0.0.1:9876/proxy"
                )
            stream.connect_grpc(run.options.rerun_url, default_blueprint=layout)
    except KeympsError:
        raise
    except Exception as error:
        raise KeympsError(f"rerun {mode} failed: {error}") from None
    from keymps.default_plugins.rerun.entities import log_world_setup
    from keymps.planning.redaction import redact_text as redact

    stream.send_recording_name(redact(f"{run.task.name} ({run.folder.name})"))
    log_world_setup(stream)
    target = run.folder / RECORDING_FILE if memory is not None else None
    return _Session(stream=stream, mode=mode, memory=memory, target=target)


def _close(key: int) -> str | None:
    """Flush and close a run's recording; the problem if it could not be delivered, else None.

    Never raises and never waits forever (a viewer that is gone must not hang the run).
    """
    session = _sessions.pop(key, None)
    if session is None:
        return None
    problem = None
    try:
        session.stream.flush(timeout_sec=FLUSH_TIMEOUT_S)
    except Exception as error:
        problem = str(error)
    problem = _disconnect(session.stream) or problem
    if session.memory is not None and session.target is not None and problem is None:
        try:
            data = session.memory.read(flush=True, flush_timeout_sec=FLUSH_TIMEOUT_S) or b""
            write_atomically(session.target, data)
        except OSError as error:
            return f"rerun save: {os_error_message(error)}"
        except Exception as error:
            problem = str(error)
    if problem is None:
        return None
    return f"rerun {session.mode}: the recording was not fully delivered: {problem}"


def _disconnect(stream: Any) -> str | None:
    """Close the stream's sink, waiting at most DISCONNECT_TIMEOUT_S; the problem, if any."""
    problems: list[str] = []

    def close() -> None:
        try:
            stream.disconnect()
        except Exception as error:
            problems.append(str(error))

    closing = threading.Thread(target=close, name="keymps-rerun-disconnect", daemon=True)
    closing.start()
    closing.join(DISCONNECT_TIMEOUT_S)
    if closing.is_alive():
        return f"the sink did not close within {DISCONNECT_TIMEOUT_S:g} s"
    return problems[0] if problems else None


def _session_for(run: Run) -> _Session | None:
    key = id(run)
    if key in _sessions:
        return _sessions[key]
    _sessions[key] = None  # a failed start is reported once, not at every stage
    # A run dropped without its "finished" event still gets its recording closed.
    weakref.finalize(run, _close, key)
    session = _open(run)
    _sessions[key] = session
    return session


def _log_stage(stream: Any, stage: str, result: Any, run: Run) -> None:
    from keymps.default_plugins.rerun import entities, motion, text

    if stage == "image":
        entities.log_image(stream, result, run)
    elif stage == "detect":
        entities.log_detection(stream, result, run)
    elif stage == "plan":
        entities.log_plan(stream, result, run)
        text.log_vlm(stream, result)
    elif stage == "ground":
        entities.log_grounding(stream, result)
    elif stage == "compose":
        motion.log_tool_path(stream, result)
    elif stage == "time":
        _log_motion(stream, result, run)
    elif stage == "check":
        text.log_validation(stream, result)
    elif stage == "execute":
        text.log_execution(stream, result, run)
        entities.log_outcome(stream, run)
        entities.log_execution_video(stream, result.files, run)


def _log_motion(stream: Any, trajectory: Any, run: Run) -> None:
    from keymps.default_plugins.rerun import motion as rerun_motion
    from keymps.default_plugins.rerun import robot as rerun_robot

    index = stage_index("time")
    rerun_motion.log_trajectory(stream, trajectory, index, ROBOT_RATE_HZ)
    robot = run.robot
    if robot is None:  # a Run built without its arm: the task's
        from keymps.robot.model import RobotModel

        robot = RobotModel.from_task(run.task)
    urdf = rerun_robot.log_robot_model(stream, robot, run.task)
    picked = rerun_motion.subsample_indices(trajectory.t, ROBOT_RATE_HZ)
    rerun_robot.log_robot_motion(stream, urdf, trajectory, picked, index)


@hookimpl
def keymps_stage_done(stage: str, result: Any, run: Run) -> None:
    """Log one stage's result to the run's recording; close the recording when the run ends."""
    if run.options.rerun == "off":
        return
    if stage == "finished" and id(run) not in _sessions and result is None:
        return
    try:
        session = _session_for(run)
        if session is None:
            return
        stream = session.stream
        stream.set_time("stage", sequence=stage_index(stage))
        stream.set_time("time", duration=0.0)
        if stage == "finished":
            from keymps.default_plugins.rerun.text import log_finished

            log_finished(stream, result if isinstance(result, BaseException) else None, run)
        else:
            _log_stage(stream, stage, result, run)
    finally:
        problem = _close(id(run)) if stage == "finished" else None
    if problem:
        raise KeympsError(problem)
