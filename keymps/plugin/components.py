"""What a plugin's factory must return, for each kind of component (typing.Protocol)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from pathlib import Path

    import numpy as np

    from keymps.types import Detection, ExecutionReport, SceneImage, ValidatedTrajectory


class ImageSource(Protocol):
    """Produces the scene image: `register_image_sources(register)`."""

    def load(self) -> SceneImage: ...


class Detector(Protocol):
    """Finds the object in the scene image: `register_detectors(register)`."""

    def detect(self, image: np.ndarray) -> Detection: ...


class VlmBackend(Protocol):
    """Answers a planning request with the planner's JSON answer: `register_vlm_backends`."""

    name: str

    def complete(self, request: Any) -> Any: ...


class Executor(Protocol):
    """Runs a validated trajectory: `register_executors(register)`."""

    def execute(self, trajectory: ValidatedTrajectory, run_folder: Path) -> ExecutionReport: ...
