"""The engine: stages in order, each announced; the first error stops everything after it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import keymps
from keymps.errors import KeympsError, StageError
from keymps.plugin.hookspecs import hookimpl
from keymps.run import RunOptions, RunOverrides
from keymps.types import STAGES, ExecutionReport

REPO = Path(__file__).resolve().parents[2]


class RecordingExecutor:
    """Stands in for a robot: records what it was asked to execute (no arm exists here)."""

    calls: list = []

    def __init__(self, options: dict) -> None:
        self.options = options

    def execute(self, validated, run) -> ExecutionReport:
        RecordingExecutor.calls.append(validated)
        return ExecutionReport(executor="recording", ok=True, message="recorded")


class BrokenDetector:
    def __init__(self, options: dict) -> None:
        pass

    def detect(self, scene):
        raise KeympsError("no object found (a detector that always fails)")


class EnginePlugin:
    def __init__(self) -> None:
        self.events: list[tuple[str, object]] = []

    @hookimpl
    def register_executors(self, register):
        register("recording", RecordingExecutor)

    @hookimpl
    def register_detectors(self, register):
        register("broken", BrokenDetector)

    @hookimpl
    def keymps_stage_done(self, stage, result, run):
        self.events.append((stage, result))


@pytest.fixture
def observer(keymps_plugins) -> EnginePlugin:
    plugin = EnginePlugin()
    keymps_plugins.register(plugin, name="engine-test-plugin")
    RecordingExecutor.calls = []
    return plugin


def _task_copy(tmp_path: Path, replace: tuple[str, str] | None = None) -> Path:
    text = (REPO / "tasks/cake_icing.yaml").read_text()
    text = text.replace("scenes/round_cake.png", str(REPO / "tasks/scenes/round_cake.png"))
    text = text.replace("../prompts/icing.md", str(REPO / "prompts/icing.md"))
    if replace:
        text = text.replace(*replace)
    path = tmp_path / "task.yaml"
    path.write_text(text)
    return path


def test_every_stage_runs_in_order_and_is_announced(tmp_path: Path, observer: EnginePlugin) -> None:
    run = keymps.run_task(
        _task_copy(tmp_path),
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(executor="recording", out=tmp_path / "run"),
    )
    stages = [stage for stage, _ in observer.events]
    assert stages == [*STAGES, "finished"]
    assert observer.events[-1][1] is None
    assert set(run.timings_s) == set(STAGES)
    assert len(RecordingExecutor.calls) == 1
    assert RecordingExecutor.calls[0] is run.stages.check
    record = json.loads((tmp_path / "run/run.json").read_text())
    assert record["ok"] is True and record["execution"]["executor"] == "recording"


def test_first_error_stops_the_run_and_no_executor_is_called(
    tmp_path: Path, observer: EnginePlugin
) -> None:
    path = _task_copy(tmp_path, ("detector: {name: board}", "detector: {name: broken}"))
    with pytest.raises(StageError, match=r"^detect: no object found"):
        keymps.run_task(
            path,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(executor="recording", out=tmp_path / "run"),
        )
    assert [stage for stage, _ in observer.events] == ["image", "finished"]
    assert isinstance(observer.events[-1][1], StageError)
    assert RecordingExecutor.calls == []
    record = json.loads((tmp_path / "run/run.json").read_text())
    assert record["ok"] is False
    assert record["error"].startswith("detect: no object found")
    assert record["keyword"] is None and record["trajectory"] is None


def test_configuration_errors_stop_before_any_stage(tmp_path: Path, observer: EnginePlugin) -> None:
    path = _task_copy(tmp_path)
    with pytest.raises(KeympsError, match=r"task.yaml:\d+:\d+: executor: unknown executor 'nope'"):
        keymps.run_task(path, overrides=RunOverrides(executor="nope", out=tmp_path / "run"))
    assert observer.events == []
    assert not (tmp_path / "run").exists()
    spoon = _task_copy(tmp_path, ("tool: piping_bag", "tool: spoon"))
    with pytest.raises(KeympsError, match=r"task.yaml:\d+:\d+: robot.tool: unknown tool 'spoon'"):
        keymps.run_task(spoon, overrides=RunOverrides(out=tmp_path / "run"))
    assert observer.events == [] and not (tmp_path / "run").exists()


def test_images_can_be_written_as_jpeg_and_other_formats_are_refused_first(
    tmp_path: Path, observer: EnginePlugin
) -> None:
    with pytest.raises(KeympsError, match="image_format 'gif' is not one of: png, jpg"):
        keymps.run_task(
            _task_copy(tmp_path),
            options=RunOptions(image_format="gif"),
            overrides=RunOverrides(out=tmp_path / "gif"),
        )
    assert observer.events == [] and not (tmp_path / "gif").exists()
    run = keymps.run_task(
        _task_copy(tmp_path),
        options=RunOptions(image_format="jpg", rerun="off"),
        overrides=RunOverrides(out=tmp_path / "jpg"),
    )
    assert (run.folder / "plan.jpg").read_bytes()[:3] == b"\xff\xd8\xff"  # a JPEG
    assert (run.folder / "outcome.jpg").is_file() and not list(run.folder.glob("*.png"))


def test_overrides_are_validated(tmp_path: Path, observer: EnginePlugin) -> None:
    with pytest.raises(KeympsError, match="override instruction"):
        keymps.run_task(
            _task_copy(tmp_path), overrides=RunOverrides(instruction="   ", out=tmp_path / "run")
        )
    with pytest.raises(KeympsError, match="--image: file not found"):
        keymps.run_task(
            _task_copy(tmp_path),
            overrides=RunOverrides(image=tmp_path / "nope.png", out=tmp_path / "r"),
        )


def test_the_deprecated_keywords_still_run_and_warn_at_the_callers_line(
    tmp_path: Path, observer: EnginePlugin
) -> None:
    """The only call of the old `run_task(task, out=..., rerun=...)` form in the tests (the
    pytest configuration turns its warning into an error everywhere else)."""
    deprecated = r"^run_task\(\*\*keywords\) is deprecated: pass options=RunOptions"
    instruction = "Put 10 icing dots around the cake"
    with pytest.warns(DeprecationWarning, match=deprecated) as caught:
        old = keymps.run_task(
            _task_copy(tmp_path),
            instruction=instruction,
            executor="recording",
            out=tmp_path / "old",
            rerun="off",
            quiet=True,
        )
    warned = [w for w in caught if issubclass(w.category, DeprecationWarning)]
    assert len(warned) == 1 and warned[0].filename == __file__
    new = keymps.run_task(
        _task_copy(tmp_path),
        options=RunOptions(rerun="off", quiet=True),
        overrides=RunOverrides(instruction=instruction, executor="recording", out=tmp_path / "new"),
    )
    assert old.folder == tmp_path / "old" and old.options == new.options
    assert old.task.instruction == new.task.instruction == instruction
    assert old.stages.execute is not None and old.stages.execute.ok
    executed_old, executed_new = (c.trajectory.q for c in RecordingExecutor.calls)
    assert executed_new is new.stages.check.trajectory.q
    assert executed_old.shape[0] > 100 and np.array_equal(executed_old, executed_new)
    with (
        pytest.warns(DeprecationWarning),
        pytest.raises(KeympsError, match=r"run option\(s\): outt"),
    ):
        keymps.run_task(_task_copy(tmp_path), outt=tmp_path / "typo")
    assert not (tmp_path / "typo").exists()


def test_a_failing_observer_is_a_warning_not_a_failed_run(tmp_path: Path, keymps_plugins) -> None:
    class Exploding:
        @hookimpl
        def keymps_stage_done(self, stage, result, run):
            if stage == "plan":
                raise RuntimeError("observer bug")

    keymps_plugins.register(Exploding(), name="exploding")
    with pytest.warns(UserWarning, match=r"failed in keymps_stage_done\(stage='plan'\)"):
        run = keymps.run_task(
            _task_copy(tmp_path),
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(out=tmp_path / "run"),
        )
    assert run.stages.execute is not None
    assert any("observer bug" in w for w in run.warnings)


def test_a_failing_observer_hides_no_stage_from_the_others(
    tmp_path: Path, observer: EnginePlugin, keymps_plugins
) -> None:
    """pluggy stops a hook call at its first exception: the observers are called one by one,
    so one registered after (called before) the others does not blind them, the recorder too."""

    class Exploding:
        @hookimpl
        def keymps_stage_done(self, stage, result, run):
            if stage == "detect":
                raise RuntimeError("observer bug")

    keymps_plugins.register(Exploding(), name="exploding")
    with pytest.warns(UserWarning) as caught:
        run = keymps.run_task(
            _task_copy(tmp_path),
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(executor="recording", out=tmp_path / "run"),
        )
    assert [stage for stage, _ in observer.events] == [*STAGES, "finished"]
    expected = (
        "keymps: plugin 'exploding' failed in keymps_stage_done(stage='detect') and was "
        "unregistered: RuntimeError: observer bug"
    )  # once: it is not called again
    assert [str(w.message) for w in caught if "exploding" in str(w.message)] == [expected]
    assert expected in run.warnings
    assert not keymps_plugins.manager.has_plugin("exploding")


class _CrashingDetector:
    def __init__(self, options: dict) -> None:
        pass

    def detect(self, scene):
        raise ZeroDivisionError("plugin bug")


class _CrashPlugin:
    @hookimpl
    def register_detectors(self, register):
        register("crashing", _CrashingDetector)


def test_a_plugin_bug_is_one_line_and_nothing_runs_after_it(
    tmp_path: Path, observer: EnginePlugin, keymps_plugins, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("KEYMPS_DEBUG", raising=False)
    keymps_plugins.register(_CrashPlugin(), name="crash-plugin")
    path = _task_copy(tmp_path, ("detector: {name: board}", "detector: {name: crashing}"))
    with pytest.raises(StageError) as caught:
        keymps.run_task(
            path,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(executor="recording", out=tmp_path / "run"),
        )
    assert str(caught.value) == (
        "detect: unexpected ZeroDivisionError: plugin bug "
        "(a bug in keymps or the detector 'crashing'; KEYMPS_DEBUG=1 shows the traceback)"
    )
    assert RecordingExecutor.calls == []
    monkeypatch.setenv("KEYMPS_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        keymps.run_task(
            path,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(executor="recording", out=tmp_path / "run2"),
        )


class _Misbehaving:
    """An image source, detector and executor returning `what` (or raising it) instead of
    their result: what a stranger's plugin may do. (No arm exists here: nothing moves.)"""

    what: object = None

    def __init__(self, options: dict) -> None:
        pass

    def _misbehave(self) -> object:
        if isinstance(_Misbehaving.what, BaseException):
            raise _Misbehaving.what
        return _Misbehaving.what

    def load(self, run):
        return self._misbehave()

    def detect(self, scene):
        return self._misbehave()

    def execute(self, validated, run):
        RecordingExecutor.calls.append(validated)
        return self._misbehave()


class _MisbehavingPlugin:
    @hookimpl
    def register_image_sources(self, register):
        register("odd-source", _Misbehaving)

    @hookimpl
    def register_detectors(self, register):
        register("odd-detector", _Misbehaving)

    @hookimpl
    def register_executors(self, register):
        register("odd-executor", _Misbehaving)


@pytest.mark.parametrize(
    ("stage", "replace", "returned", "message"),
    [
        ("execute", None, None, "executor 'odd-executor' returned None, not an ExecutionReport"),
        (
            "execute",
            None,
            {"ok": True},
            "executor 'odd-executor' returned dict, not an ExecutionReport",
        ),
        (
            "detect",
            ("detector: {name: board}", "detector: {name: odd-detector}"),
            None,
            "detector 'odd-detector' returned None, not a Detection",
        ),
        (
            "image",
            ("scene:\n", "scene:\n  source: odd-source\n"),
            "photo.png",
            "image source 'odd-source' returned str, not a SceneImage",
        ),
        (
            "image",
            ("scene:\n", "scene:\n  source: odd-source\n"),
            OSError("camera unplugged"),
            "camera unplugged",
        ),
    ],
)
def test_a_plugin_returning_something_else_is_one_line_recorded_in_run_json(
    tmp_path: Path,
    observer: EnginePlugin,
    keymps_plugins,
    stage: str,
    replace: tuple[str, str] | None,
    returned: object,
    message: str,
) -> None:
    keymps_plugins.register(_MisbehavingPlugin(), name="misbehaving")
    _Misbehaving.what = returned
    path = _task_copy(tmp_path, replace)
    with pytest.raises(StageError) as caught:
        keymps.run_task(
            path,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(executor="odd-executor", out=tmp_path / "run"),
        )
    assert str(caught.value) == f"{stage}: {message}"
    record = json.loads((tmp_path / "run/run.json").read_text())
    assert record["status"] == "failed"
    assert message in record["error"]
    if stage != "execute":
        assert RecordingExecutor.calls == []  # nothing after the failed stage ran


def test_an_image_that_does_not_span_the_workspace_is_a_warning(
    tmp_path: Path, observer: EnginePlugin
) -> None:
    """A square photo of the 0.30 x 0.18 m board: pixels 0.50 mm wide and 0.30 mm tall."""
    import cv2

    image = cv2.imread(str(REPO / "tasks/scenes/round_cake.png"))
    cv2.imwrite(str(tmp_path / "square.png"), cv2.resize(image, (600, 600)))
    run = keymps.run_task(
        _task_copy(tmp_path),
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(image=tmp_path / "square.png", out=tmp_path / "run"),
    )
    expected = "a pixel is 0.50 mm wide and 0.30 mm tall: crop the image to the board"
    assert any(expected in warning for warning in run.warnings), run.warnings
    record = json.loads((tmp_path / "run/run.json").read_text())
    assert any(expected in warning for warning in record["warnings"])
    same_shape = keymps.run_task(
        _task_copy(tmp_path),
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(out=tmp_path / "plain"),
    )
    assert not any("a pixel is" in warning for warning in same_shape.warnings)


def test_out_is_a_new_or_empty_folder_or_an_earlier_runs(tmp_path: Path) -> None:
    """`keymps run --out tasks` wrote run.json, plan.png and trajectory.csv among the task
    files; run_task itself writes where it is told (eval reruns interrupted folders)."""
    from click.testing import CliRunner

    from keymps.cli.app import cli

    others = tmp_path / "tasks"
    others.mkdir()
    (others / "mine.yaml").write_text("name: mine\n")
    task = str(_task_copy(tmp_path))
    result = CliRunner().invoke(cli, ["run", task, "--rerun", "off", "--out", str(others)])
    assert result.exit_code == 1
    assert result.output.strip().endswith(
        f"--out {others}: the folder holds other files and no run.json (it is no run folder): "
        "name a new or empty folder, or an earlier run's"
    )
    assert sorted(p.name for p in others.iterdir()) == ["mine.yaml"]
    again = tmp_path / "run"
    for _ in range(2):  # an earlier run's folder is a run folder: its files are replaced
        result = CliRunner().invoke(cli, ["run", task, "--rerun", "off", "--out", str(again)])
        assert result.exit_code == 0, result.output


def test_an_api_base_override_that_is_no_url_stops_before_the_run(tmp_path: Path) -> None:
    """`--api-base not-a-url` was retried for 18 s and reported as 'HTTP 500'."""
    with pytest.raises(KeympsError) as caught:
        keymps.run_task(
            _task_copy(tmp_path), overrides=RunOverrides(api_base="not-a-url", out=tmp_path / "run")
        )
    assert str(caught.value) == (
        "override planner.api_base: 'not-a-url' is not an http(s) URL with a host "
        "(e.g. http://127.0.0.1:8000/v1)"
    )
    assert not (tmp_path / "run").exists()


def test_rerun_connect_to_an_address_that_is_no_viewer_stops_before_the_run(
    tmp_path: Path,
) -> None:
    """`--rerun connect --rerun-url http://...` ran on, warning at every stage, exit 0."""
    with pytest.raises(KeympsError, match=r"--rerun-url 'http://127.0.0.1:9' is no Rerun viewer"):
        keymps.run_task(
            _task_copy(tmp_path),
            options=RunOptions(rerun="connect", rerun_url="http://127.0.0.1:9"),
            overrides=RunOverrides(out=tmp_path / "run"),
        )
    assert not (tmp_path / "run").exists()


def test_a_run_into_an_earlier_runs_folder_leaves_none_of_its_files(tmp_path: Path) -> None:
    """A failed run into the folder of a finished one kept the old trajectory.csv, plan.png and
    run.rrd beside its own failed run.json: a script reading the folder took the old motion."""
    task, folder = _task_copy(tmp_path), tmp_path / "run"
    keymps.run_task(
        task, options=RunOptions(rerun="save"), overrides=RunOverrides(out=folder, executor="file")
    )
    written = {p.name for p in folder.iterdir()}
    assert {"trajectory.csv", "trajectory.json", "plan.png", "run.rrd", "vlm"} <= written
    (folder / "notes.txt").write_text("mine")  # not a file a run writes: kept
    outside = tmp_path / "kept.json"
    outside.write_text("{}")
    (folder / "vlm" / "linked.json").symlink_to(outside)  # a link: removed, never its target
    with pytest.raises(KeympsError, match="cannot turn 'asdf' into a design"):
        keymps.run_task(
            task,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(out=folder, instruction="asdf"),
        )
    assert sorted(p.name for p in folder.iterdir()) == [
        ".keymps.lock",
        "notes.txt",
        "run.json",
        "vlm",
    ]
    assert json.loads((folder / "run.json").read_text())["status"] == "failed"
    assert "linked.json" not in {p.name for p in (folder / "vlm").iterdir()} and outside.exists()


def test_an_earlier_runs_file_that_cannot_be_removed_stops_the_run(tmp_path: Path) -> None:
    task, folder = _task_copy(tmp_path), tmp_path / "run"
    keymps.run_task(task, options=RunOptions(rerun="off"), overrides=RunOverrides(out=folder))
    (folder / "trajectory.csv").unlink()
    (folder / "trajectory.csv").mkdir()  # unlink() cannot remove a folder
    with pytest.raises(KeympsError) as caught:
        keymps.run_task(task, options=RunOptions(rerun="off"), overrides=RunOverrides(out=folder))
    assert str(caught.value) == (
        f"{folder}: cannot remove the earlier run's trajectory.csv: Is a directory"
    )
    assert (folder / "run.json").exists()  # removed last: still an earlier run's folder


def test_a_folder_without_run_json_is_not_cleared(tmp_path: Path) -> None:
    """run_task writes where it is told; only a folder holding a run's record is an earlier run's."""
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "trajectory.csv").write_text("not keymps'")  # a run through ground writes none
    keymps.run_task(
        _task_copy(tmp_path),
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(out=folder),
        through="ground",
    )
    assert (folder / "trajectory.csv").read_text() == "not keymps'"
    assert (folder / "run.json").exists()
