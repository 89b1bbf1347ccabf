"""What a plugin's factory must return, for each kind of component: exactly what the engine
calls (mypy checks the built-in plugins and the first-party plugin packages against these)."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

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

    def load(self, run: Run) -> SceneImage:
        """Produce the scene image of this run.

        Args:
            run: The run (its `task.scene` says what to load; `task.resolve` finds files).

        Returns:
            The top-down image (BGR, uint8) and where it came from.

        Raises:
            ImageSourceError: When there is no image to give (one line, no traceback).
        """
        ...


class Detector(Protocol):
    """Finds the object(s) in the scene image: `register_detectors(register)`.

    Raise DetectionError when there is none.
    """

    def detect(self, scene: SceneImage) -> Detection:
        """Find the object(s) in the scene image.

        Args:
            scene: The image source's result.

        Returns:
            The object's box and crop in full-image pixels, every object found, and a report.

        Raises:
            DetectionError: When there is no object (an empty board is refused, not guessed).
        """
        ...


class VlmBackend(Protocol):
    """Answers a planning request with the planner's JSON answer: `register_vlm_backends`.

    What a backend can do beyond `complete` is declared by inheriting BackendBase and setting
    its ability flags; a backend that does not inherit it gets the flags' defaults.

    Optional: `def prepare() -> None`, a slow set-up (an import) started on a thread as soon as
    a run knows it will use the backend; BackendBase.prepare says when, on which thread and
    what it may do (a backend without it needs no set-up).
    """

    name: str
    """The backend's registered name (run.json's `backend`)."""

    def complete(self, request: PlanRequest) -> BackendAnswer:
        """Answer one planning call.

        Args:
            request: The rendered chat, the crop, the answer's JSON schema and the limits.

        Returns:
            The answer's text (the planner's JSON; keymps checks it and asks again on a
            problem) with its token counts, latency and cost when known.

        Raises:
            keymps.errors.KeympsError: When no answer can be had (one line, keys redacted).
        """
        ...


class BackendBase:
    """A base class for planner backends whose class attributes declare what they can do.

    Inheriting it is optional: keymps reads the same flags from a backend that does not inherit
    it (one written against the plain VlmBackend Protocol) and uses each default it lacks.
    """

    name: str = ""
    """The backend's registered name (run.json's `backend`)."""
    asks_model: ClassVar[bool] = True
    """False for a planner that is no model (the offline one): run.json and the eval tables count
    no VLM call for it, and it is sent the crop at full size in pixel coordinates."""
    cacheable: ClassVar[bool] = False
    """True lets keymps keep its answers in the on-disk answer cache (paid or slow backends);
    `planner.cache: false` and `--no-cache` still turn the cache off."""
    supports_async: ClassVar[bool] = False
    """True when `acomplete` is implemented: `keymps eval` then makes many of its calls at once
    on one event loop instead of calling `complete` from each run's thread."""

    def complete(self, request: PlanRequest) -> BackendAnswer:
        """Answer one planning call (see VlmBackend.complete).

        Args:
            request: The call: step, prompt, crop, JSON schema and answer mode.

        Returns:
            The backend's answer text and what it cost.
        """
        raise NotImplementedError(f"{type(self).__name__} does not implement complete()")

    async def acomplete(self, request: PlanRequest) -> BackendAnswer:
        """Answer one planning call on an event loop; only called when `supports_async`.

        Args:
            request: The call, as for `complete`.

        Returns:
            The backend's answer text and what it cost.
        """
        raise NotImplementedError(f"{type(self).__name__} does not implement acomplete()")

    def prepare(self) -> None:
        """Do a slow one-off set-up before the first call (an import, a cache); by default nothing.

        When: once a run knows it will plan with this backend, before its image is read (and
        once per process in `keymps eval`), so that the set-up overlaps the stages before
        planning. Where: on a background thread ("keymps-backend-prepare"), on an object made
        for this alone; the plan stage makes its own backend and may call `complete` while
        `prepare` still runs. So it may import libraries and fill process-wide caches, but
        must keep nothing on `self` that `complete` relies on, must be safe to run beside
        `complete`, and must send no key anywhere. Its errors are ignored there (the plan
        stage makes the backend again and reports what is wrong).
        """


@dataclass(frozen=True)
class BackendAbilities:
    """What one backend object can do: its BackendBase flags, or their defaults."""

    asks_model: bool = BackendBase.asks_model
    """Whether it asks a model (its answers are recorded and cached as a model's)."""
    cacheable: bool = BackendBase.cacheable
    """Whether its answers may be kept in the plan cache and reused."""
    supports_async: bool = BackendBase.supports_async
    """Whether `keymps eval` may call its `acomplete` on the broker's event loop."""

    @classmethod
    def of(cls, backend: object) -> BackendAbilities:
        """The flags a backend declares (on BackendBase or as plain class attributes).

        Args:
            backend: A planner backend object.

        Returns:
            Its abilities; each flag it does not declare has BackendBase's default.
        """
        flags = {flag.name: flag.default for flag in fields(cls)}
        return cls(
            **{flag: bool(getattr(backend, flag, default)) for flag, default in flags.items()}
        )


def prepare_backend(backend: object) -> None:
    """Run a backend's `prepare()` (BackendBase.prepare); a backend written against the plain
    VlmBackend Protocol may lack it, and then there is nothing to do.

    Args:
        backend: A planner backend object.
    """
    prepare = getattr(backend, "prepare", None)
    if callable(prepare):
        prepare()


class Executor(Protocol):
    """Runs a validated trajectory: `register_executors(register)`.

    It must call `require_validated(validated, name)` before moving anything.
    """

    name: str
    """The executor's registered name (run.json's `execution.executor`)."""

    def execute(self, validated: ValidatedTrajectory, run: Run) -> ExecutionReport:
        """Carry out a trajectory the safety check issued.

        Args:
            validated: The checked trajectory; `require_validated(validated, name)` gives it
                back only when it is unchanged since the check.
            run: The run (its folder for files, `options.confirm` for real robots).

        Returns:
            What it did: its verdict, one line, the files it wrote and its figures.

        Raises:
            keymps.errors.SafetyError: When the trajectory was not issued by the check.
        """
        ...


class StageObserver(Protocol):
    """A plugin that watches runs: its `keymps_stage_done` hook sees each stage's result."""

    def keymps_stage_done(self, stage: str, result: Any, run: Run) -> None:
        """See a finished stage (and once more with stage "finished" at the end of the run).

        Args:
            stage: The stage's name (image, detect, plan ... execute), or "finished".
            result: The stage's typed result (keymps.types); for "finished", the run's error
                or None.
            run: The run (its typed context).
        """
        ...


class Arm(Protocol):
    """A robot arm: what `register_robots` factories return.

    Usually a keymps.plugin.ArmSpec, whose fields document each of these.
    """

    @property
    def name(self) -> str:
        """The model name (`robot.model`)."""
        ...

    @property
    def urdf(self) -> Path:
        """The URDF file."""
        ...

    @property
    def tip_link(self) -> str:
        """The link the tool is mounted on."""
        ...

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The arm's joints in the controller's order (() for root to tip)."""
        ...

    @property
    def velocity_limits(self) -> tuple[float, ...] | None:
        """rad/s per joint (None: the URDF's)."""
        ...

    @property
    def acceleration_limits(self) -> tuple[float, ...] | None:
        """rad/s^2 per joint (None: keymps' default)."""
        ...

    @property
    def jerk_limits(self) -> tuple[float, ...] | None:
        """rad/s^3 per joint (None: keymps' default)."""
        ...

    @property
    def position_limits(self) -> tuple[tuple[float, float], ...] | None:
        """(lower, upper) per joint (None: the URDF's)."""
        ...

    @property
    def effort_limits(self) -> tuple[float, ...] | None:
        """N m per joint (None: the URDF's)."""
        ...

    @property
    def home(self) -> tuple[float, ...] | None:
        """Where the inverse kinematics starts (None: zeros)."""
        ...

    @property
    def rate_hz(self) -> float:
        """The controller's rate, Hz."""
        ...

    @property
    def dh(self) -> tuple[float, float, float, float, float, float] | None:
        """A UR-type DH table (the closed-form IK), or None."""
        ...

    @property
    def package_dirs(self) -> tuple[Path, ...]:
        """Folders the URDF's meshes may be read from."""
        ...

    @property
    def collision_padding(self) -> float:
        """Metres added to every clearance the safety check demands."""
        ...

    @property
    def mesh_scales(self) -> tuple[tuple[str, tuple[float, float, float]], ...]:
        """(link, scale) extra scales of links' meshes."""
        ...

    @property
    def description(self) -> str:
        """One line naming the arm."""
        ...

    def base_for(self, board_size: tuple[float, float]) -> Pose4:
        """The default placement on a board.

        Args:
            board_size: The board's (width, height), metres.

        Returns:
            (x, y, z, yaw) of the root link in the board frame, metres and degrees.
        """
        ...
