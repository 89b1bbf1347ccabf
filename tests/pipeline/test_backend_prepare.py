"""A run starts its planner backend's slow set-up (`prepare()`, litellm's import) on a thread as
soon as it knows the backend, before its first stage, and a set-up that fails changes nothing.

The detector of these runs waits until the backend's `prepare` has begun: a run that called it
only at the plan stage, or not at all, would never get past detection (the wait is bounded only
as a guard against hanging)."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest
from helpers.fuzz_support import answer_text, task_copy

from keymps import run_task
from keymps.errors import KeympsError
from keymps.plugin import hookimpl
from keymps.run import RunOptions, RunOverrides
from keymps.types import BackendAnswer, PlanRequest, SceneImage

BEGUN = threading.Event()
CALLS: list[tuple[str, str]] = []


class PreparingBackend:
    name = "preparing"
    fails = False

    def __init__(self, options: dict[str, Any]) -> None:
        self.options = options

    def prepare(self) -> None:
        CALLS.append(("prepare", threading.current_thread().name))
        BEGUN.set()
        if PreparingBackend.fails:
            raise RuntimeError("the set-up failed")

    def complete(self, request: PlanRequest) -> BackendAnswer:
        CALLS.append(("complete", threading.current_thread().name))
        return BackendAnswer(text=answer_text("line", [[[130, 130], [130, 130]]]))


class WaitingDetector:
    """The board detector, once the backend's set-up has begun."""

    def __init__(self, options: dict[str, Any], board: Any) -> None:
        self.board = board

    def detect(self, scene: SceneImage) -> Any:
        if not BEGUN.wait(120):
            raise KeympsError("the backend's prepare() had not begun when the scene was read")
        return self.board.detect(scene)


@pytest.mark.parametrize("fails", [False, True])
def test_the_backend_is_prepared_on_a_thread_before_the_first_stage(
    fails: bool, keymps_plugins: Any, tmp_path: Path
) -> None:
    board = keymps_plugins.create("detector", "board")

    class Plugin:
        @hookimpl
        def register_vlm_backends(self, register: Any) -> None:
            register("preparing", PreparingBackend)

        @hookimpl
        def register_detectors(self, register: Any) -> None:
            register("waiting", lambda options: WaitingDetector(options, board))

    keymps_plugins.register(Plugin(), name="preparing-plugin")
    BEGUN.clear()
    CALLS.clear()
    PreparingBackend.fails = fails
    task = task_copy(
        tmp_path / "task",
        **{"backend: auto": "backend: preparing", "detector: {name: board}": "detector: {name: waiting}"},
    )  # fmt: skip
    run = run_task(
        task,
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(out=tmp_path / "run", executor="file"),
    )
    assert run.stages.plan is not None and run.stages.plan.keyword == "line"
    assert CALLS == [
        ("prepare", "keymps-backend-prepare"),
        ("complete", "MainThread"),
    ]


def test_an_offline_run_prepares_nothing(keymps_plugins: Any, tmp_path: Path) -> None:
    CALLS.clear()
    task = task_copy(tmp_path / "task")
    run_task(
        task,
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(out=tmp_path / "run", executor="file", backend="offline"),
    )
    assert not [t for t in threading.enumerate() if t.name == "keymps-backend-prepare"]
    assert CALLS == []
