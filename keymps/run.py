"""The state of one run: its task, its folder, the results of the stages done so far."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from keymps.config.task import Task
from keymps.errors import KeympsError

IMAGE_FORMATS = ("png", "jpg")
JPEG_QUALITY = 92


@dataclass
class RunOptions:
    """Choices made on the command line (or by run_task keywords), not in the task file."""

    rerun: str = "save"
    """save | spawn | connect | off"""
    rerun_url: str | None = None
    no_cache: bool = False
    record: Path | None = None
    """Write every VLM request digest and answer to this cassette (JSONL)."""
    confirm: bool = False
    """Real-robot executors move the arm only when this is set."""
    quiet: bool = False
    image_format: str = "png"
    """plan and outcome images: png (lossless) or jpg (a tenth of the size and of the time to
    write: `keymps eval`'s default, for hundreds of runs)."""


@dataclass
class Run:
    """Passed to every `keymps_stage_done` observer and to executors."""

    task: Task
    folder: Path
    options: RunOptions = field(default_factory=RunOptions)
    results: dict[str, Any] = field(default_factory=dict)
    """Stage name -> that stage's result ('image', 'detect', 'plan', ... 'execute')."""
    timings_s: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    notes: dict[str, Any] = field(default_factory=dict)
    """Free-form facts for run.json (backend choice and why, cache hits ...)."""

    def path(self, name: str) -> Path:
        """A file in the run folder (its parent folders created)."""
        target = self.folder / name
        target.parent.mkdir(parents=True, exist_ok=True)
        return target

    def image_path(self, stem: str) -> Path:
        """Where the run's image `stem` (plan, outcome) is, in the run's image format."""
        return image_file(self.folder, stem, self.options.image_format)

    def write_image(self, stem: str, image: Any) -> Path:
        """Write a BGR image as `stem` in the run folder, in the run's image format."""
        self.folder.mkdir(parents=True, exist_ok=True)
        return write_image(self.image_path(stem), image)


def image_file(folder: Path, stem: str, image_format: str) -> Path:
    """The file of image `stem` (plan, outcome) in `folder`, for one of IMAGE_FORMATS."""
    return folder / f"{stem}.{image_format}"


def write_image(path: Path, image: Any) -> Path:
    """Write a BGR image; the suffix (.png or .jpg) chooses the format."""
    import cv2

    options = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if path.suffix == ".jpg" else []
    if not cv2.imwrite(str(path), image, options):
        raise KeympsError(f"cannot write {path}")
    return path
