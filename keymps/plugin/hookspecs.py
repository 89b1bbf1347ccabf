"""Hook specifications: what a keymps plugin can provide (every hook is in docs/plugins.md)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

from pluggy import HookimplMarker, HookspecMarker

from keymps.plugin.components import Arm, Detector, Executor, ImageSource, VlmBackend

if TYPE_CHECKING:
    from keymps.run import Run

hookspec = HookspecMarker("keymps")
hookimpl = HookimplMarker("keymps")
"""Marks a plugin's hook implementation: `@hookimpl def register_detectors(register): ...`."""

Component = TypeVar("Component")
Factory = Callable[[dict[str, Any]], Component]
"""factory(options) returns the component; options are the task file's section for it."""
Register = Callable[[str, Factory[Component]], None]
"""register(name, factory). Parameterized (Register[Detector]) mypy checks the factory's
component against the Protocol the engine calls."""

RegisterDetector = Register[Detector]
"""The callback `register_detectors` receives: register(name, factory -> Detector)."""
RegisterVlmBackend = Register[VlmBackend]
"""The callback `register_vlm_backends` receives: register(name, factory -> VlmBackend)."""
RegisterExecutor = Register[Executor]
"""The callback `register_executors` receives: register(name, factory -> Executor)."""
RegisterImageSource = Register[ImageSource]
"""The callback `register_image_sources` receives: register(name, factory -> ImageSource)."""
RegisterRobot = Register[Arm]
"""The callback `register_robots` receives: register(name, factory -> Arm, e.g. an ArmSpec)."""


@hookspec
def register_detectors(register: RegisterDetector) -> None:
    """Register object detectors: factory(options) -> Detector."""


@hookspec
def register_vlm_backends(register: RegisterVlmBackend) -> None:
    """Register planner backends: factory(options) -> VlmBackend."""


@hookspec
def register_executors(register: RegisterExecutor) -> None:
    """Register executors: factory(options) -> Executor."""


@hookspec
def register_image_sources(register: RegisterImageSource) -> None:
    """Register image sources: factory(options) -> ImageSource."""


@hookspec
def register_robots(register: RegisterRobot) -> None:
    """Register robot arms: factory(options) -> Arm (an ArmSpec), selected by `robot.model`."""


@hookspec
def keymps_stage_done(stage: str, result: Any, run: Run) -> None:
    """Observe a finished stage: its name, its typed result and the Run (its typed context).

    Called once more with stage "finished" and the run's error (None when it succeeded).
    """
