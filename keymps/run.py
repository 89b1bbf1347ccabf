"""The state of one run: its task, its folder, the results of the stages done so far."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from keymps.config.task import Task
from keymps.errors import KeympsError
from keymps.run_files import image_file
from keymps.types import STAGES

if TYPE_CHECKING:
    import numpy as np

    from keymps.plugin.components import VlmBackend
    from keymps.robot.model import RobotModel
    from keymps.types import (
        AnswerMode,
        BackendAnswer,
        Detection,
        ExecutionReport,
        GroundedObject,
        Grounding,
        JointPath,
        Outcome,
        Plan,
        PlanRequest,
        SceneImage,
        ToolPath,
        Trajectory,
        ValidatedTrajectory,
    )


@dataclass
class RunOptions:
    """How a run is carried out (`keymps run`'s options that are no task field)."""

    rerun: str = "save"
    """save | spawn | connect | off"""
    rerun_url: str | None = None
    """The viewer to stream to with `rerun="connect"` (rerun+http://127.0.0.1:9876/proxy)."""
    no_cache: bool = False
    """Always ask the backend: never answer from the on-disk answer cache."""
    record: Path | None = None
    """Write every VLM request digest and answer to this cassette (JSONL)."""
    confirm: bool = False
    """Real-robot executors move the arm only when this is set."""
    accept_outcome: bool = False
    """Execute a plan whose predicted outcome contradicts its intent (an expert's override of
    the outcome stage; run.json records it)."""
    quiet: bool = False
    """Print nothing but the run folder (the CLI's -q; plugins may read it too)."""
    image_format: str = "png"
    """plan and outcome images: png (lossless) or jpg (a tenth of the size and of the time to
    write: `keymps eval`'s default, for hundreds of runs)."""
    dispatch: Callable[[VlmBackend, PlanRequest], BackendAnswer] | None = None
    """dispatch(backend, request) -> BackendAnswer: hands each call of a backend declaring
    `supports_async` elsewhere instead of calling `complete`: to an event loop (`keymps eval`'s
    broker), or to the warm planner (keymps.planning.warm)."""
    warm_planner: str = "off"
    """Whether litellm's calls go to the warm planner: off (never; run_task's default), use
    (when one is up: the keymps command's default) or start (starting one when none is up)."""


@dataclass(frozen=True)
class RunOverrides:
    """What a run changes of its task file (`keymps run`'s options): None keeps the file's."""

    instruction: str | None = None
    """The sentence to plan for instead of the task's `instruction` (`-i`)."""
    image: Path | None = None
    """A scene image file used instead of the task's scene (`--image`; `scene.source` becomes
    `file`)."""
    backend: str | None = None
    """The planner backend (`planner.backend`): auto, offline, litellm, replay or a plugin's."""
    model: str | None = None
    """The VLM model (`planner.model`), litellm's name, e.g. `openai/gpt-4o`."""
    api_base: str | None = None
    """The OpenAI-compatible server to ask (`planner.api_base`); given here it counts as the
    user's own, so a key may go to it."""
    cassette: Path | None = None
    """The cassette the replay backend answers from (`planner.cassette`)."""
    answer: AnswerMode | None = None
    """The form of answer asked for (`planner.answer`): pairs, design or either."""
    executor: str | None = None
    """The executor (`executor.name`): sim, file, urscript or a plugin's (ur-rtde ...)."""
    out: Path | None = None
    """The run folder (default `runs/<task>-<time>/`); an earlier run's files in it are
    replaced."""

    def __post_init__(self) -> None:
        for name in ("image", "cassette", "out"):  # a str given for a path is taken as one
            value = getattr(self, name)
            if value is not None and not isinstance(value, Path):
                object.__setattr__(self, name, Path(value))

    def task_changes(self) -> dict[str, Any]:
        """The task fields this changes, by override name.

        Returns:
            {override name: value} for every field set but `out` (what apply_overrides takes).
        """
        changes = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "out"}
        return {name: value for name, value in changes.items() if value is not None}


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
    """How the run is carried out (the command line's or run_task's `options`)."""
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
