"""What a plugin's factory must return, for each kind of component: exactly what the engine
calls (mypy checks the built-in plugins and the first-party plugin packages against these)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from pathlib import Path

    from keymps.plugin.arms import Pose4
    from keymps.run import Run
    from keymps.types import (
        BackendAnswer,
        Detection,
        ExecutionReport,
        PlanRequest,
        SceneImage,
        ValidatedTrajectory,
    )


class ImageSource(Protocol):
    """Produces the scene image: `register_image_sources(register)`; raise ImageSourceError."""

    def load(self, run: Run) -> SceneImage: ...


class Detector(Protocol):
    """Finds the object(s) in the scene image: `register_detectors(register)`; raise
    DetectionError when there is none."""

    def detect(self, scene: SceneImage) -> Detection: ...


class VlmBackend(Protocol):
    """Answers a planning request with the planner's JSON answer: `register_vlm_backends`.

    Optional: `cacheable = True` lets keymps cache answers on disk (paid or slow backends),
    `asks_model = False` keeps its answers out of the VLM call counts (the offline planner), and
    `async def acomplete(request)` lets `keymps eval` make many calls at once on one event loop.
    """

    name: str

    def complete(self, request: PlanRequest) -> BackendAnswer: ...


class Executor(Protocol):
    """Runs a validated trajectory: `register_executors(register)`. It must call
    keymps.robot.safety.require_validated(validated, name) before moving anything."""

    name: str

    def execute(self, validated: ValidatedTrajectory, run: Run) -> ExecutionReport: ...


class StageObserver(Protocol):
    """A plugin that watches runs: its `keymps_stage_done` hook sees each stage's result."""

    def keymps_stage_done(self, stage: str, result: Any, run: Run) -> None: ...


class Arm(Protocol):
    """A robot arm: `register_robots(register)`; factory(options) returns one, usually a
    keymps.plugin.ArmSpec (the attributes are documented there)."""

    @property
    def name(self) -> str: ...
    @property
    def urdf(self) -> Path: ...
    @property
    def tip_link(self) -> str: ...
    @property
    def joint_names(self) -> tuple[str, ...]: ...
    @property
    def velocity_limits(self) -> tuple[float, ...] | None: ...
    @property
    def acceleration_limits(self) -> tuple[float, ...] | None: ...
    @property
    def jerk_limits(self) -> tuple[float, ...] | None: ...
    @property
    def position_limits(self) -> tuple[tuple[float, float], ...] | None: ...
    @property
    def effort_limits(self) -> tuple[float, ...] | None: ...
    @property
    def home(self) -> tuple[float, ...] | None: ...
    @property
    def rate_hz(self) -> float: ...
    @property
    def dh(self) -> tuple[float, float, float, float, float, float] | None: ...
    @property
    def package_dirs(self) -> tuple[Path, ...]: ...
    @property
    def collision_padding(self) -> float: ...
    @property
    def mesh_scales(self) -> tuple[tuple[str, tuple[float, float, float]], ...]: ...
    @property
    def description(self) -> str: ...

    def base_for(self, board_size: tuple[float, float]) -> Pose4: ...
