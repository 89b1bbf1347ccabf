"""Helpers for the fuzz suites: a scripted VLM backend, a recording executor, task copies.

RecordingExecutor stands in for a robot (no arm exists in the tests): it records every
trajectory it is asked to execute, so a test can assert that nothing reached it after an error.
ScriptedBackend is a real planner backend plugin whose answers the test sets.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import HealthCheck, settings

from keymps.errors import KeympsError
from keymps.plugin.hookspecs import hookimpl
from keymps.types import BackendAnswer, ExecutionReport, PlanRequest

FAST = settings(deadline=None, suppress_health_check=list(HealthCheck), database=None)
"""The fuzz suites' base settings: no deadline (runs vary), no health checks, no example file."""

REPO = Path(__file__).resolve().parents[2]
ONE_LINE = re.compile(r"^[^\n]+$")


class RecordingExecutor:
    """Stands in for a robot: records what it is asked to execute; moves nothing."""

    calls: list[Any] = []

    def __init__(self, options: dict[str, Any]) -> None:
        self.options = options

    def execute(self, validated: Any, run: Any) -> ExecutionReport:
        from keymps.plugin import require_validated

        require_validated(validated, "recording")  # what every real executor must do
        RecordingExecutor.calls.append(validated)
        return ExecutionReport(executor="recording", ok=True, message="recorded")


class ScriptedBackend:
    """A planner backend plugin answering with the texts in `ScriptedBackend.answers`, in turn.

    A callable entry is called with the PlanRequest (it may answer, or raise).
    """

    name = "scripted"
    cacheable = False
    answers: list[Any] = []
    requests: list[PlanRequest] = []

    def __init__(self, options: dict[str, Any]) -> None:
        self.options = options

    def complete(self, request: PlanRequest) -> BackendAnswer:
        ScriptedBackend.requests.append(request)
        if not ScriptedBackend.answers:
            raise KeympsError("scripted backend: no answer left")
        answer = ScriptedBackend.answers.pop(0)
        if callable(answer):
            answer = answer(request)
        return BackendAnswer(text=answer, latency_s=0.0, model="scripted")


class FuzzPlugin:
    @hookimpl
    def register_executors(self, register: Any) -> None:
        register("recording", RecordingExecutor)

    @hookimpl
    def register_vlm_backends(self, register: Any) -> None:
        register("scripted", ScriptedBackend)


def install(harness: Any) -> None:
    """Register the fuzz plugin in a keymps_plugins harness and clear the recordings."""
    if not harness.manager.has_plugin("fuzz-plugin"):
        harness.register(FuzzPlugin(), name="fuzz-plugin")
    RecordingExecutor.calls = []
    ScriptedBackend.answers = []
    ScriptedBackend.requests = []


def task_copy(folder: Path, source: str = "cake_icing.yaml", **replace: str) -> Path:
    """A copy of a shipped task with absolute paths (and text replacements) in `folder`."""
    text = (REPO / "tasks" / source).read_text()
    text = text.replace("scenes/", f"{REPO}/tasks/scenes/")
    text = text.replace("../prompts/", f"{REPO}/prompts/")
    for old, new in replace.items():
        text = text.replace(old, new)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "task.yaml"
    path.write_text(text)
    return path


def plan_request(timeout_s: float, schema: dict[str, Any] | None = None) -> PlanRequest:
    """A small one-dot planning request for a backend called directly (no run around it)."""
    return PlanRequest(
        instruction="Put 1 icing dot",
        crop=np.zeros((8, 8, 3), np.uint8),
        crop_mask=None,
        metres_per_px=(0.001, 0.001),
        primitives={"line": "a line"},
        object_height=0.05,
        max_pairs=4,
        messages=[{"role": "user", "content": "plan"}],
        schema=schema or {},
        timeout_s=timeout_s,
    )


def answer_text(keyword: str, pairs: Any, rationale: str = "fuzz") -> str:
    return json.dumps({"keyword": keyword, "pairs": pairs, "rationale": rationale})


def assert_clean_error(error: BaseException) -> None:
    """A KeympsError with one line naming the problem (what the CLI prints after 'error: ')."""
    assert isinstance(error, KeympsError), f"{type(error).__name__}: {error}"
    message = str(error)
    assert ONE_LINE.match(message), repr(message[:300])
    assert "Traceback" not in message


def workspace_box(task: Any, size_px: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The board-frame xy extent of the image (the workspace), from the task's pixel mapping."""
    from keymps.perception.frames import ImageFrame

    width, height = size_px
    corners = np.array([[0, 0], [width, 0], [width, height], [0, height]], dtype=float)
    board = ImageFrame.from_task(task, size_px).to_board(corners)
    return board.min(axis=0), board.max(axis=0)


def finite(values: Any) -> bool:
    return all(math.isfinite(v) for v in np.asarray(values, dtype=float).ravel())
