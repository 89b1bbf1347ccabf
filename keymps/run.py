"""The state of one run: its task, its folder, the results of the stages done so far."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from keymps.config.task import Task
from keymps.errors import KeympsError
from keymps.run_files import image_file
from keymps.types import STAGES

if TYPE_CHECKING:
    import numpy as np

    from keymps.robot.model import RobotModel
    from keymps.types import (
        Detection,
        ExecutionReport,
        GroundedObject,
        Grounding,
        JointPath,
        Outcome,
        Plan,
        SceneImage,
        ToolPath,
        Trajectory,
        ValidatedTrajectory,
    )


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
    accept_outcome: bool = False
    """Execute a plan whose predicted outcome contradicts its intent (an expert's override of
    the outcome stage; run.json records it)."""
    quiet: bool = False
    image_format: str = "png"
    """plan and outcome images: png (lossless) or jpg (a tenth of the size and of the time to
    write: `keymps eval`'s default, for hundreds of runs)."""
    dispatch: Callable[[Any, Any], Any] | None = None
    """dispatch(backend, request) -> BackendAnswer: hands each call of a backend that offers
    `acomplete` elsewhere instead of calling `complete`: to an event loop (`keymps eval`'s
    broker), or to the warm planner (keymps.planning.warm)."""
    warm_planner: str = "off"
    """Whether litellm's calls go to the warm planner: off (never; run_task's default), use
    (when one is up: the keymps command's default) or start (starting one when none is up)."""


@dataclass
class StageResults:
    """What each stage of a run produced, typed; None until that stage has run."""

    image: SceneImage | None = None
    detect: Detection | None = None
    plan: Plan | None = None
    ground: Grounding | None = None
    compose: ToolPath | None = None
    solve: JointPath | None = None
    time: Trajectory | None = None
    check: ValidatedTrajectory | None = None
    outcome: Outcome | None = None
    execute: ExecutionReport | None = None

    def record(self, stage: str, result: Any) -> None:
        """Store `result` as the result of `stage` (one of STAGES)."""
        if stage not in STAGES:
            raise KeympsError(f"unknown stage {stage!r} (stages: {', '.join(STAGES)})")
        setattr(self, stage, result)


@dataclass
class Run:
    """The run's typed context: passed to every `keymps_stage_done` observer and to executors."""

    task: Task
    """The task being run, command-line overrides applied."""
    folder: Path
    """The run folder (`runs/<task>-<time>/` or `--out`): run.json and every file of the run."""
    options: RunOptions = field(default_factory=RunOptions)
    """Choices made on the command line or by run_task's keywords, not in the task file."""
    stages: StageResults = field(default_factory=StageResults)
    """Each stage's typed result (`run.stages.plan` ...), None until that stage has run."""
    robot: RobotModel | None = None
    """The arm the run plans for (base placed on the board, the task's tool)."""
    outline_m: np.ndarray | None = None
    """(N, 2) the object's footprint in board metres, once detected and grounded."""
    objects: tuple[GroundedObject, ...] = ()
    """Every object found (id, name, height, footprint in board metres), once detected."""
    backend: str | None = None
    """The planner backend the run uses (offline, litellm, replay ...), once chosen."""
    backend_reason: str | None = None
    """Why that backend (`auto` explains its choice)."""
    timings_s: dict[str, float] = field(default_factory=dict)
    """Seconds each finished stage took, by stage name (run.json's timings_s)."""
    warnings: list[str] = field(default_factory=list)
    """What the run noticed without stopping (the detector's doubts, a slowed work piece ...),
    one line each, in order."""

    def path(self, name: str) -> Path:
        """A file in the run folder, its parent folders created.

        Args:
            name: The file's path relative to the run folder (`vlm/answer-1.json`).

        Returns:
            The path inside `folder` (the file itself is not created).
        """
        target = self.folder / name
        target.parent.mkdir(parents=True, exist_ok=True)
        return target

    def image_path(self, stem: str) -> Path:
        """Where one of the run's images is, in the run's image format.

        Args:
            stem: The image's name without suffix (`plan`, `outcome`).

        Returns:
            `folder / "<stem>.png"` (or `.jpg` with `image_format="jpg"`).
        """
        return image_file(self.folder, stem, self.options.image_format)

    def write_image(self, stem: str, image: Any) -> Path:
        """Write an image into the run folder atomically, in the run's image format.

        Args:
            stem: The image's name without suffix (`plan`, `outcome`).
            image: (H, W, 3) BGR uint8 array.

        Returns:
            The path written.

        Raises:
            keymps.errors.KeympsError: When OpenCV cannot encode the image.
        """
        from keymps.run_files import write_image  # looked up here: a benchmark swaps it

        self.folder.mkdir(parents=True, exist_ok=True)
        return write_image(self.image_path(stem), image)
