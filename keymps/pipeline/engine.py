"""Runs a task stage by stage: each timed, each announced, the first error stops everything."""

from __future__ import annotations

import dataclasses
import os
import re
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from keymps.config.overrides import apply_overrides
from keymps.config.task import Task, load_task
from keymps.errors import (
    Interrupted,
    KeympsError,
    RunInterrupted,
    StageError,
    TaskFileError,
    interrupt_name,
    os_error_message,
)
from keymps.interrupts import first_signal, interrupts_deferred, signals_received
from keymps.pipeline import stages
from keymps.planning.backend_choice import AUTO_VLM, NO_SERVER
from keymps.plugin.manager import (
    call_each,
    create_detector,
    create_executor,
    create_image_source,
    get_manager,
)
from keymps.run import Run, RunOptions, RunOverrides
from keymps.run_files import IMAGE_FORMATS
from keymps.types import (
    STAGES,
    Detection,
    ExecutionReport,
    Outcome,
    Plan,
    SceneImage,
    ValidatedTrajectory,
)

if TYPE_CHECKING:
    from keymps.pipeline.folder_lock import FolderLock
    from keymps.plugin.components import Detector, Executor, ImageSource
    from keymps.primitives.dictionary import Primitive
    from keymps.robot.model import RobotModel

Result = TypeVar("Result")
Part = TypeVar("Part")

RERUN_SCHEMES = ("rerun+http://", "rerun+https://", "rerun://")
"""How a Rerun viewer's address begins (--rerun connect)."""

StageCallback = Callable[[str, float, Any], None]
"""on_stage(stage, seconds, result): called after each stage (the CLI shows progress with it)."""


class Components:
    """Everything a run needs, built before the first stage so configuration errors cost nothing.

    A run that stops after planning (`through="ground"`) builds no executor and no robot; one
    that stops after the outcome stage, no executor.
    Every part is built even when another fails: the TaskFileError raised lists them all.
    Parts named in `skip` (task fields already known to be wrong) are left as None.
    """

    image_source: ImageSource | None
    detector: Detector | None
    executor: Executor | None
    primitives: dict[str, Primitive] | None
    robot: RobotModel | None
    backend: str
    """The planner backend's registered name (built by the plan stage, which knows its task)."""

    def __init__(
        self,
        task: Task,
        backend: str,
        through: str = "execute",
        skip: frozenset[str] = frozenset(),
    ):
        from keymps.primitives.dictionary import default_search_dirs, load_primitives

        executes = STAGES.index(through) > STAGES.index("ground")
        problems: list[str] = []

        def build(field: str, make: Callable[[], Part]) -> Part | None:
            if field in skip:
                return None
            try:
                return make()
            except TaskFileError as error:
                problems.extend(error.problems)
            except KeympsError as error:
                problems.append(str(error))
            return None

        scene, detector, executor = task.scene, task.detector, task.executor
        self.image_source = build(
            "scene",
            lambda: _located_field(
                task,
                ("scene", "source"),
                lambda: create_image_source(scene.source, scene.source_options),
            ),
        )
        self.detector = build(
            "detector",
            lambda: _located_field(
                task, ("detector",), lambda: create_detector(detector.name, detector.options)
            ),
        )
        self.executor = None
        if through == "execute":
            self.executor = build(
                "executor",
                lambda: _located_field(
                    task, ("executor",), lambda: create_executor(executor.name, executor.options)
                ),
            )
        self.primitives = build(
            "primitives",
            lambda: _primitives(task, load_primitives, default_search_dirs(task.folder)),
        )
        self.robot = build("robot", lambda: _robot(task)) if executes else None
        self.backend = backend
        if problems:
            raise TaskFileError(problems)


def _primitives(
    task: Task,
    load: Callable[[list[str], list[Path]], dict[str, Primitive]],
    search: list[Path],
) -> dict[str, Primitive]:
    try:
        return load(task.primitives, search)
    except KeympsError as error:
        raise KeympsError(f"{task.where('primitives')}: primitives: {error}") from None


def _robot(task: Task) -> RobotModel:
    """The task's arm, built by the robot plugin that registered it (`robot.model`, or `urdf`
    for the task's own URDF), placed and tooled; every error located in the task file."""
    from keymps.robot.model import RobotModel, arm_by_name

    field = ("robot", "urdf") if task.robot.urdf is not None else ("robot", "model")
    where = f"{task.where(*field)}: {'.'.join(field)}"
    try:
        arm = arm_by_name(*task.robot.arm_component(task.folder))
    except KeympsError as error:
        raise KeympsError(f"{where}: {error}") from None
    try:
        robot = RobotModel.from_task(task, arm)
    except KeympsError as error:
        located = _located(task, error)
        if located is error and str(error).startswith("robot: arm "):
            located = KeympsError(f"{where}: {str(error).removeprefix('robot: ')}")
        raise located from None
    too_high = robot.height_problem()  # a height error, not "out of reach" after planning
    if too_high:
        field, name = _tallest_height_field(task)
        raise KeympsError(f"{task.where(*field)}: {name}: {too_high}")
    return robot


def _tallest_height_field(task: Task) -> tuple[tuple[Any, ...], str]:
    """Where the task file sets its tallest object's height, and the field's name."""
    tallest = task.scene.tallest_object_height
    for index, spec in enumerate(task.scene.objects or ()):
        if spec.height is not None and spec.height == tallest:
            return ("scene", "objects", index, "height"), f"scene.objects[{index}].height"
    return ("scene", "object_height"), "scene.object_height"


_FIELD_PREFIX = re.compile(r"^([a-z_]+(?:\.[a-z_]+)+): ")
"""An error that starts with a task field ("robot.tool: ...") can point into the task file."""


def _located(task: Task, error: KeympsError) -> KeympsError:
    """The error with the file:line:col of the task field it names, when it names one."""
    named = _FIELD_PREFIX.match(str(error))
    if named is None:
        return error
    return KeympsError(f"{task.where(*named.group(1).split('.'))}: {error}")


def _located_field(task: Task, field_path: tuple[str, ...], create: Callable[[], Part]) -> Part:
    """`create()`, its error located at the task field that named the component."""
    try:
        return create()
    except KeympsError as error:
        raise KeympsError(f"{task.where(*field_path)}: {'.'.join(field_path)}: {error}") from None


def refuse_a_folder_of_other_files(out: Path) -> None:
    """The keymps command's --out names a run folder: a new or empty one, or an earlier run's
    (run.json in it, its files replaced); never a folder of other files (`--out tasks`, `--out
    ""` for the cwd). run_task itself writes where it is told (eval reruns an interrupted run's
    folder in place)."""
    if not out.is_dir():
        return
    try:
        names = {entry.name for entry in out.iterdir()}
    except OSError as error:
        raise KeympsError(f"--out {out}: cannot list the run folder: {error.strerror}") from None
    if names - {".keymps.lock"} and "run.json" not in names:
        raise KeympsError(
            f"--out {str(out) or '.'}: the folder holds other files and no run.json (it is no "
            "run folder): name a new or empty folder, or an earlier run's"
        )


def _new_run_folder(task: Task, out: Path | None) -> Path:
    if out is not None:
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as error:  # a file of that name, a read-only place ...
            reason = error.strerror
            if out.is_symlink() and not out.exists():
                reason = "a symbolic link that leads nowhere (a loop or a missing target)"
            raise KeympsError(f"--out {out}: cannot create the run folder: {reason}") from None
        return out
    stamp = time.strftime("%Y%m%d-%H%M%S")
    base = Path("runs") / f"{task.name}-{stamp}"
    folder, n = base, 1
    while folder.exists():
        n += 1
        folder = base.with_name(f"{base.name}-{n}")
    try:
        folder.mkdir(parents=True)
    except OSError as error:
        raise KeympsError(
            f"cannot create the run folder {folder}: {error.strerror} (choose one with --out)"
        ) from None
    return folder


class _Pipeline:
    """The stage sequence of one run (Alg. 1 of the paper, plus solve/time/check/execute)."""

    def __init__(self, run: Run, parts: Components, on_stage: StageCallback | None, through: str):
        self.run = run
        self.parts = parts
        self.on_stage = on_stage
        self.through = through
        self.manager = get_manager()
        self.current: str | None = None
        """The stage running, if any, and the last one done: where an interrupt stopped it."""
        self.done: str | None = None
        self.perception: stages.Perception | None = None
        """What the image and detect stages found, once they have run."""

    @property
    def primitives(self) -> dict[str, Primitive]:
        """The run's primitives, by name (Components built them before the first stage)."""
        assert self.parts.primitives is not None
        return self.parts.primitives

    def stage(self, name: str, work: Callable[[], Any]) -> Any:
        started = time.perf_counter()
        self.current = name
        signals_before = signals_received()
        try:
            result = work()
        except StageError as error:
            if error.stage != name:  # a stage's own error passes as it is; another's is wrapped
                raise StageError(name, str(error), detail=error) from None
            raise
        except KeympsError as error:
            raise StageError(name, str(error), detail=error) from None
        except OSError as error:  # a full disk, a read-only folder ...: the path, in one line
            if error.errno is None:  # raised by a plugin with its own words ("camera unplugged")
                message = " ".join(str(error).split()) or type(error).__name__
                raise StageError(name, message, detail=error) from None
            if error.filename is None:  # a failed write() names no file
                error = OSError(error.errno, error.strerror, f"a file in {self.run.folder}")
            raise StageError(name, os_error_message(error), detail=error) from None
        except Exception as error:
            # A bug in keymps or in a plugin: still one line (and nothing after this stage
            # runs); KEYMPS_DEBUG=1 shows the traceback for whoever fixes it.
            if os.environ.get("KEYMPS_DEBUG"):
                raise
            detail = " ".join(str(error).split()) or "no message"
            plugin = self.plugin_of(name)
            suspects = f"keymps or the {plugin}" if plugin else "keymps or a plugin"
            raise StageError(
                name,
                f"unexpected {type(error).__name__}: {detail} "
                f"(a bug in {suspects}; KEYMPS_DEBUG=1 shows the traceback)",
            ) from error
        seconds = time.perf_counter() - started
        if signals_received() > signals_before:  # a stop signal the stage's code swallowed (an
            self.run.stages.record(name, result)  # executor that stopped the arm and returned)
            raise Interrupted(first_signal())
        self.current, self.done = None, name
        self.run.stages.record(name, result)
        self.run.timings_s[name] = self.run.timings_s.get(name, 0.0) + seconds  # repair rounds
        if self.on_stage:
            self.on_stage(name, seconds, result)
        self.announce(name, result)
        return result

    def returned(self, stage: str, result: Result, expected: type[Result]) -> Result:
        """A plugin's result, refused in one line unless it is of the documented type (an
        executor returning None must not pass as a finished run)."""
        if not isinstance(result, expected):
            got = "None" if result is None else type(result).__name__
            wanted = expected.__name__
            article = "an" if wanted[0] in "AEIOU" else "a"
            raise KeympsError(f"{self.plugin_of(stage)} returned {got}, not {article} {wanted}")
        return result

    def plugin_of(self, stage: str) -> str | None:
        """The plugin whose code a stage calls ("executor 'sim'"), for a bug's one line."""
        task = self.run.task
        return {
            "image": f"image source {task.scene.source!r}",
            "detect": f"detector {task.detector.name!r}",
            "plan": f"planner backend {self.parts.backend!r}",
            "execute": f"executor {task.executor.name!r}",
        }.get(stage)

    def announce(self, name: str, result: Any) -> None:
        """Tell the observers, each on its own: one that raises is unregistered with one
        warning naming it, and the others, the Rerun recorder among them, still see the
        stage (the user's Ctrl-C goes on after them)."""
        problems = call_each(
            self.manager, "keymps_stage_done", stage=name, result=result, run=self.run
        )
        self.run.warnings.extend(problems)

    def execute_all(self) -> None:
        from keymps.motion.trajectory_io import write_trajectory_csv

        run, parts = self.run, self.parts
        scene, detection, objects = self.perceive()
        repair: list[tuple[str, list[str]]] = []
        while True:
            plan = self.replan(scene, detection, objects, repair)
            done = self.plan_to_outcome(scene, detection, objects, plan)
            if done is None:
                return  # through="ground"
            if done.outcome.ok:
                break
            repair = self.repair_or_stop(plan, done.outcome, repair)
        if self.through == "outcome":
            return
        validated = done.validated
        _write_file(lambda: write_trajectory_csv(validated.trajectory, run.path("trajectory.csv")))
        executor = parts.executor
        assert executor is not None  # Components built it to execute
        report = self.stage(
            "execute",
            lambda: self.returned("execute", executor.execute(validated, run), ExecutionReport),
        )
        if not report.ok:
            raise StageError("execute", report.message or f"executor {report.executor} failed")
        self.compare(done.outcome, report)

    def perceive(self) -> tuple[SceneImage, Detection, Any]:
        """The image and detect stages: the scene, the detection and the scene's objects."""
        from keymps.perception import frames as geometry

        run, parts, task = self.run, self.parts, self.run.task
        source, detector, primitives = parts.image_source, parts.detector, parts.primitives
        assert source is not None and detector is not None and primitives is not None  # built
        # with board corners, every later stage works in the rectified top-down image
        scene: SceneImage = self.stage(
            "image",
            lambda: stages.rectified(task, self.returned("image", source.load(run), SceneImage)),
        )
        pixel_shape = geometry.pixel_shape_warning(task, scene.size_px)
        if pixel_shape:
            run.warnings.append(pixel_shape)

        def detect() -> Detection:
            detected = self.returned("detect", detector.detect(scene), Detection)
            self.perception = stages.detected(task, scene, detected)
            run.objects, run.outline_m = self.perception.grounded, self.perception.outline_m
            return self.perception.detection

        detection = self.stage("detect", detect)
        run.warnings.extend(detection.warnings)
        assert self.perception is not None  # the detect stage sets it
        return scene, detection, self.perception.objects

    def replan(
        self,
        scene: SceneImage,
        detection: Detection,
        objects: Any,
        repair: list[tuple[str, list[str]]],
    ) -> Plan:
        """The plan stage; in a repair round, a plan that fails names the outcome it repairs."""
        try:
            return self.plan(scene, detection, objects, repair)
        except StageError as error:
            outcome = self.run.stages.outcome
            if not repair or outcome is None:
                raise
            raise StageError(
                "outcome",
                _one_line(outcome, len(repair), f"; the repair round failed: {error}"),
                detail=error,
            ) from None

    def plan(
        self,
        scene: SceneImage,
        detection: Detection,
        objects: Any,
        repair: list[tuple[str, list[str]]],
    ) -> Plan:
        """The plan stage (again, with the problems of the earlier rounds' outcomes), plan.png."""
        from keymps.pipeline.overlay import draw_plan, draw_plan_on_photo

        run, parts, task, perception = self.run, self.parts, self.run.task, self.perception
        assert perception is not None  # the detect stage ran
        plan: Plan = self.stage(
            "plan",
            lambda: stages.plan(task, perception, self.primitives, run, parts.backend, repair),
        )
        _write_file(lambda: run.write_image("plan", draw_plan(scene.image, detection, plan)))
        on_photo = draw_plan_on_photo(scene, detection, plan)
        if on_photo is not None:
            _write_file(lambda: run.write_image("plan_photo", on_photo))
        return plan

    def plan_to_outcome(
        self, scene: SceneImage, detection: Detection, objects: Any, plan: Plan
    ) -> _Checked | None:
        """ground, compose, solve, time, check and outcome for one plan (None: through ground)."""
        from keymps.config.limits import check_duration, check_tool_path
        from keymps.motion.chains import JOIN_LINE_WIDTHS
        from keymps.motion.compose import compose_tool_path
        from keymps.motion.timing import time_trajectory
        from keymps.robot.model import solve_path
        from keymps.robot.safety import validate

        run, parts, task = self.run, self.parts, self.run.task
        perception = self.perception
        assert perception is not None  # the detect stage ran
        grounding = self.stage("ground", lambda: stages.ground(task, perception, plan))
        if self.through == "ground":
            return None
        robot = parts.robot
        assert robot is not None  # Components built it to go on
        tool_path = self.stage(
            "compose",
            lambda: check_tool_path(
                compose_tool_path(
                    grounding.segments,
                    self.primitives[plan.keyword],
                    object_top=grounding.object_height,
                    clearance=task.motion.clearance,
                    work_speed=task.motion.work_speed,
                    travel_speed=task.motion.travel_speed,
                    yaw_mode=robot.tool.yaw,
                    home=robot.home_tool_position(),
                    home_yaw=robot.home_yaw(),
                    footprint=run.outline_m,
                    objects=grounding.objects,
                    join_distance=JOIN_LINE_WIDTHS * robot.tool.line_width,
                    blade_length=robot.tool.blade_length,
                ),
                task,
            ),
        )
        joint_path = self.stage("solve", lambda: solve_path(robot, tool_path))
        trajectory = self.stage(
            "time",
            lambda: check_duration(time_trajectory(robot, tool_path, joint_path, task), task),
        )
        run.warnings.extend(trajectory.warnings)
        validated = self.stage(
            "check", lambda: validate(robot, trajectory, tool_path, grounding.objects, task)
        )
        outcome = self.stage("outcome", lambda: self.predict(plan, grounding, tool_path, validated))
        return _Checked(validated, outcome)

    def predict(
        self, plan: Plan, grounding: Any, tool_path: Any, validated: ValidatedTrajectory
    ) -> Outcome:
        """The outcome stage: the predicted effect and the verdict; plan_outcome.png."""
        from keymps.outcome.check import check_outcome, foods_of, stated_intents
        from keymps.outcome.picture import draw_outcome
        from keymps.outcome.predict import Tool
        from keymps.planning.intent import sentence_intent

        run, parts, task = self.run, self.parts, self.run.task
        robot = parts.robot
        assert robot is not None
        family = self.primitives[plan.keyword].family
        tool = Tool(family != "icing", robot.tool.blade_length, robot.tool.line_width)
        foods = foods_of(grounding.objects, run.outline_m, grounding.object_height)
        asked = sentence_intent(task.instruction)
        intents = stated_intents(plan.intents, task, asked, objects=len(foods))
        accept = run.options.accept_outcome
        outcome = check_outcome(
            robot, validated.trajectory, tool_path, foods, tool, intents, accept
        )
        scene = run.stages.image
        if scene is not None:
            picture = draw_outcome(scene, task, foods, outcome)
            _write_file(lambda: run.write_image("plan_outcome", picture))
        if outcome.verdict == "accepted":
            run.warnings.append(
                "--accept-outcome: executed although the predicted outcome is wrong: "
                + "; ".join(outcome.problems)
            )
        return outcome

    def repair_or_stop(
        self, plan: Plan, outcome: Outcome, repair: list[tuple[str, list[str]]]
    ) -> list[tuple[str, list[str]]]:
        """The repair history for one more plan round, or the outcome's StageError when the
        backend asks no model (the offline planner answers the same again) or the rounds
        (planner.attempts) are spent."""
        from keymps.planning.prompt import OUTCOME_PROBLEM

        rounds = len(repair) + 1
        asks_model = any(call.model_call for call in plan.calls)
        if not asks_model or rounds >= self.run.task.planner.attempts or not plan.calls:
            raise StageError("outcome", _one_line(outcome, rounds if asks_model else 0))
        problems = [f"{OUTCOME_PROBLEM}{p}" for p in outcome.problems]
        intents = "; ".join(i.describe() for i in outcome.intents) or "none stated"
        problems.append(f"{OUTCOME_PROBLEM}the intent checked: {intents}")
        return [*repair, (plan.calls[-1].answer_text, problems)]

    def compare(self, outcome: Outcome, report: ExecutionReport) -> None:
        """A measured result that falls short of the prediction makes the run not ok."""
        from keymps.outcome.measured import measured_problems

        if report.measured is None:
            return
        problems = measured_problems(outcome.predicted, report.measured)
        self.run.stages.outcome = replace(
            outcome, measured=report.measured, measured_problems=tuple(problems)
        )
        if problems:
            more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
            raise StageError(
                "execute",
                f"executor {report.executor}: the measured result falls short of the "
                f"prediction: {problems[0]}{more}",
            )


@dataclass(frozen=True)
class _Checked:
    """A plan that went through the safety check, and its outcome."""

    validated: ValidatedTrajectory
    outcome: Outcome


def _one_line(outcome: Outcome, rounds: int, after: str = "") -> str:
    """The outcome's refusal: its first problem, how many more, the rounds tried, `after`."""
    first = outcome.problems[0]
    count = len(outcome.problems)
    more = f" (and {count - 1} more in run.json)" if count > 1 else ""
    tried = f"; {rounds} plan rounds with the VLM" if rounds > 1 else ""
    return (
        f"the predicted outcome is wrong: {first}{more}{tried}{after}; nothing was executed "
        "(--accept-outcome executes it anyway)"
    )


def _write_file(write: Callable[[], Any]) -> None:
    """A run-folder file written between stages: an OSError becomes one line naming it."""
    try:
        write()
    except OSError as error:
        raise KeympsError(os_error_message(error)) from None


def _write_record(run: Run, error: BaseException | None, pipeline: _Pipeline) -> str | None:
    """Write run.json (an interrupt recorded as such); the problem if it could not be written."""
    from keymps.pipeline.run_folder import write_run_json

    if isinstance(error, KeyboardInterrupt):
        error = RunInterrupted(pipeline.current, pipeline.done, interrupt_name(error))
    try:
        write_run_json(run, error)
    except OSError as failure:
        return os_error_message(failure)
    return None


def _backend_under_way(task: Task, backend: str, options: RunOptions) -> RunOptions:
    """The run's options with the plan stage's backend got going before the first stage: its
    calls handed to the warm planner (one is up, or asked to start), or else its own set-up
    (litellm's import, seconds) started on a thread, to overlap the stages before planning."""
    if backend in NO_SERVER or options.dispatch is not None:  # (eval's broker warms up itself)
        return options
    from keymps.planning.planner import backend_options, prepare_backend_in_background
    from keymps.planning.warm.dispatch import warm_dispatch

    if backend == AUTO_VLM:
        dispatch = warm_dispatch(options.warm_planner)
        if dispatch is not None:
            return replace(options, dispatch=dispatch)
    prepare_backend_in_background(backend, backend_options(task))
    return options


def _prepare_folder(run: Run) -> None:
    """Remove an earlier run's files, then write the placeholder run.json that holds the disk
    space of the record (a run.json that is a folder, a full disk: refused before any stage)."""
    from keymps.pipeline.run_folder import clear_earlier_run, reserve_run_json

    clear_earlier_run(run.folder)
    with interrupts_deferred():
        try:
            reserve_run_json(run)
        except OSError as error:
            raise KeympsError(
                f"{os_error_message(error)} (run.json is written before the first stage)"
            ) from None


def run_task(
    task: Task | str | Path,
    *,
    on_stage: StageCallback | None = None,
    options: RunOptions | None = None,
    overrides: RunOverrides | None = None,
    through: str = "execute",
    **keywords: Any,
) -> Run:
    """Run a task end to end; return the finished Run (its folder holds run.json and the rest).

    `options` say how the run is carried out, `overrides` what it changes of the task file.
    `through="ground"` stops after grounding the plan (eval's plan-only runs): nothing is timed,
    checked or executed; `through="outcome"` stops after the outcome stage (its repair
    rounds included): nothing is executed. Raises KeympsError on the first problem;
    nothing after the failing stage runs, above all no executor. `**keywords` (the fields
    of both, by name) are deprecated.
    """
    from keymps.planning.backend_choice import untrusted_api_base_warning
    from keymps.planning.planner import choose_backend
    from keymps.text_drawing import prepare_text_drawing

    if not isinstance(task, Task):
        task = load_task(task)
    options, overrides = apply_deprecated_keywords(
        options or RunOptions(), overrides or RunOverrides(), keywords
    )
    _check_options(options, through)
    task = apply_overrides(task, overrides.task_changes())
    backend, reason = choose_backend(task, overrides.backend, overrides.model, overrides.api_base)
    options = _backend_under_way(task, backend, options)
    prepare_text_drawing()  # OpenCV's font set-up, on the other core until plan.png is drawn
    parts = Components(task, backend, through)
    _refuse_files_not_to_send(task, parts, overrides)
    run, lock = _start_run(task, options, overrides.out)
    run.backend, run.backend_reason, run.robot = backend, reason, parts.robot
    keyless = untrusted_api_base_warning(task) if backend not in NO_SERVER else None
    if keyless:
        run.warnings.append(keyless)
        warnings.warn(keyless, UserWarning, stacklevel=2)
    return _run_stages(_Pipeline(run, parts, on_stage, through), lock)


def apply_deprecated_keywords(
    options: RunOptions, overrides: RunOverrides, keywords: dict[str, Any]
) -> tuple[RunOptions, RunOverrides]:
    """`options` and `overrides` with run_task's deprecated keyword arguments applied.

    Args:
        options: How the run is carried out.
        overrides: What it changes of the task file.
        keywords: run_task's deprecated keyword arguments (a DeprecationWarning when any).

    Returns:
        The options and overrides with each keyword set on the one that has its field.

    Raises:
        KeympsError: Naming a keyword neither has.
    """
    if not keywords:
        return options, overrides
    warnings.warn(
        "run_task(**keywords) is deprecated: pass options=RunOptions(...) and "
        "overrides=RunOverrides(...) (keymps.run)",
        DeprecationWarning,
        stacklevel=3,
    )
    option_names = {f.name for f in dataclasses.fields(RunOptions)}
    override_names = {f.name for f in dataclasses.fields(RunOverrides)}
    unknown = sorted(set(keywords) - option_names - override_names)
    if unknown:
        raise KeympsError(f"unknown run option(s): {', '.join(unknown)}")
    given = {k: v for k, v in keywords.items() if k in override_names and v is not None}
    return (
        dataclasses.replace(options, **{k: v for k, v in keywords.items() if k in option_names}),
        dataclasses.replace(overrides, **given),
    )


def _check_options(options: RunOptions, through: str) -> None:
    """Refuse options no run can carry out, before anything is built."""
    if options.image_format not in IMAGE_FORMATS:
        raise KeympsError(
            f"image_format {options.image_format!r} is not one of: {', '.join(IMAGE_FORMATS)}"
        )
    if options.rerun == "connect" and not str(options.rerun_url or "").startswith(RERUN_SCHEMES):
        # else the run went on, recording nothing, with a warning per stage
        raise KeympsError(
            f"--rerun-url {options.rerun_url!r} is no Rerun viewer URL: one starts with "
            f"{', '.join(RERUN_SCHEMES)} (the viewer prints it, e.g. "
            "rerun+http://127.0.0.1:9876/proxy)"
        )
    if through not in ("ground", "outcome", "execute"):
        raise KeympsError(f"through={through!r}: a run goes through ground, outcome or execute")


def _refuse_files_not_to_send(task: Task, parts: Components, overrides: RunOverrides) -> None:
    """What the run may not send its server, refused before any stage."""
    from keymps.planning.sent_files import files_refused

    if parts.backend in NO_SERVER:
        return
    described = {name: p.description for name, p in (parts.primitives or {}).items()}
    refused = files_refused(task, described, image_given=overrides.image is not None)
    if refused:
        raise KeympsError(refused[0])


def _start_run(task: Task, options: RunOptions, out: Path | None) -> tuple[Run, FolderLock]:
    """The run and its folder's lock, the folder created and cleared of an earlier run's
    files (the lock released here when it cannot be)."""
    from keymps.pipeline.folder_lock import FolderLock

    folder = _new_run_folder(task, out)
    lock = FolderLock(folder).acquire()  # a second run into this folder refuses here
    run = Run(task=task, folder=folder, options=options)
    try:
        _prepare_folder(run)
    except BaseException:
        lock.release()
        raise
    return run, lock


def _run_stages(pipeline: _Pipeline, lock: FolderLock) -> Run:
    """Run the stages, tell the observers the run finished, write run.json, release the lock;
    the run's own error is raised."""
    run = pipeline.run
    error: BaseException | None = None
    problem: str | None = None
    try:
        pipeline.execute_all()
    except BaseException as caught:
        error = caught
        if isinstance(caught, KeympsError):
            caught.run = run
        raise
    finally:
        late: KeyboardInterrupt | None = None
        try:
            try:
                pipeline.announce("finished", error)
            except KeyboardInterrupt as caught:  # Ctrl-C while the recording closes
                late = caught
            with interrupts_deferred():  # run.json is written, whatever the user presses
                problem = _write_record(run, error or late, pipeline)
        finally:
            lock.release()
        if late is not None:
            raise late
        if problem and error is not None:  # the run's own error is the one reported
            warnings.warn(f"run.json not written: {problem}", RuntimeWarning, stacklevel=3)
    if problem:
        raise KeympsError(problem)
    return run
