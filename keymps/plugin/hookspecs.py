"""Hook specifications: what a keymps plugin can provide."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pluggy import HookimplMarker, HookspecMarker

hookspec = HookspecMarker("keymps")
hookimpl = HookimplMarker("keymps")

Register = Callable[[str, Callable[..., Any]], None]
"""register(name, factory): factory(options) returns the component."""


@hookspec
def register_detectors(register: Register) -> None:
    """Register object detectors: factory(options) -> object with detect(scene) -> Detection."""


@hookspec
def register_vlm_backends(register: Register) -> None:
    """Register planner backends: factory(options) -> object with complete(request)."""


@hookspec
def register_executors(register: Register) -> None:
    """Register executors: factory(options) -> object with execute(validated, run) -> report."""


@hookspec
def register_image_sources(register: Register) -> None:
    """Register image sources: factory(options) -> object with load(run) -> SceneImage."""


@hookspec
def keymps_stage_done(stage: str, result: Any, run: Any) -> None:
    """Observe a finished stage: its name, its result and the Run it belongs to."""
