"""Resource bounds: requests that would need unbounded memory or time are refused early.

The bounds (keymps/config/limits.py, docs/safety.md): scene.max_image_pixels (from the file header,
before decoding; see also test_image_io_fuzz.py), planner.max_pairs and the answer length it
implies, motion.max_path_length and motion.max_duration_s (estimated right after composing,
before inverse kinematics, and measured after timing).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.budget import Budget
from helpers.fuzz_support import (
    RecordingExecutor,
    ScriptedBackend,
    answer_text,
    assert_clean_error,
    install,
    task_copy,
)

import keymps
from keymps.config.limits import check_duration, check_tool_path, max_answer_chars
from keymps.errors import KeympsError, TaskFileError
from keymps.run import RunOptions, RunOverrides
from keymps.types import Piece, ToolPath


def _grid_of_dots(request: Any, count: int) -> str:
    width, height = request.crop_size_px
    side = int(np.ceil(np.sqrt(count)))
    pairs = []
    for index in range(count):
        x = width * (0.3 + 0.4 * (index % side) / side)
        y = height * (0.3 + 0.4 * (index // side) / side)
        pairs.append([[x, y], [x, y]])
    return answer_text("line", pairs)


def _run(path: Path, out: Path, count: int) -> Any:
    ScriptedBackend.answers = [lambda request: _grid_of_dots(request, count)] * 2
    return keymps.run_task(
        path,
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(backend="scripted", executor="recording", out=out),
    )


def test_ten_thousand_pairs_are_refused_before_inverse_kinematics(
    keymps_plugins: Any, tmp_path: Path
) -> None:
    install(keymps_plugins)
    path = task_copy(tmp_path / "task", **{"prompt: ": "max_pairs: 10000\n  prompt: "})
    budget = Budget()
    with pytest.raises(KeympsError) as caught:
        _run(path, tmp_path / "run", 10_000)
    assert_clean_error(caught.value)
    assert str(caught.value).startswith("compose: the tool path is ")
    assert "more than motion.max_path_length = 50 m" in str(caught.value)
    assert RecordingExecutor.calls == []
    budget.check(20.0, "refused before inverse kinematics")


def test_the_default_max_pairs_refuses_65_pairs(keymps_plugins: Any, tmp_path: Path) -> None:
    install(keymps_plugins)
    with pytest.raises(KeympsError, match=r"plan: .*65 pairs given; give between 1 and 64"):
        _run(task_copy(tmp_path / "task"), tmp_path / "run", 65)
    assert RecordingExecutor.calls == []


def test_path_length_and_duration_limits_are_configurable(
    keymps_plugins: Any, tmp_path: Path
) -> None:
    install(keymps_plugins)
    short = task_copy(
        tmp_path / "short", **{"travel_speed: 0.15}": "travel_speed: 0.15, max_path_length: 0.5}"}
    )
    with pytest.raises(KeympsError, match=r"compose: the tool path is \d+\.\d m long .* = 0.5 m"):
        _run(short, tmp_path / "r1", 12)
    quick = task_copy(
        tmp_path / "quick", **{"travel_speed: 0.15}": "travel_speed: 0.15, max_duration_s: 3}"}
    )
    with pytest.raises(KeympsError, match=r"compose: the tool path would take at least \d+ s"):
        _run(quick, tmp_path / "r2", 12)
    assert RecordingExecutor.calls == []
    run = _run(task_copy(tmp_path / "default"), tmp_path / "r3", 3)  # the defaults let it run
    assert run.stages.execute.ok and len(RecordingExecutor.calls) == 1


def test_the_measured_duration_is_checked_after_timing(keymps_plugins: Any, tmp_path: Path) -> None:
    """The estimate ignores acceleration; the timed trajectory is checked against the limit too."""
    install(keymps_plugins)
    run = _run(task_copy(tmp_path / "task"), tmp_path / "run", 2)
    trajectory, tool_path = run.stages.time, run.stages.compose
    estimate = sum(p.length_m / p.speed for p in tool_path.pieces if len(p.points) > 1)
    assert trajectory.duration_s > estimate
    limit = (estimate + trajectory.duration_s) / 2
    task = run.task.model_copy(
        update={"motion": run.task.motion.model_copy(update={"max_duration_s": limit})}
    )
    assert check_tool_path(tool_path, task) is tool_path  # the estimate passes
    with pytest.raises(KeympsError, match=r"the trajectory lasts \d+ s, more than"):
        check_duration(trajectory, task)


def test_the_path_length_is_every_moving_piece_summed(tmp_path: Path) -> None:
    line = np.array([[0.0, 0.0, 0.1], [0.3, 0.0, 0.1], [0.3, 0.4, 0.1]])
    dot = np.array([[0.1, 0.1, 0.1]])
    path = ToolPath(
        (Piece("travel", 0, line, np.zeros(3), 0.1), Piece("work", 0, dot, np.zeros(1), 0.03)),
        "line",
    )
    task = keymps.load_task(task_copy(tmp_path / "task"))

    def limited(metres: float) -> Any:
        motion = task.motion.model_copy(update={"max_path_length": metres})
        return task.model_copy(update={"motion": motion})

    assert check_tool_path(path, limited(0.71)) is path
    with pytest.raises(KeympsError, match=r"the tool path is 0\.7 m long \(2 pieces\)"):
        check_tool_path(path, limited(0.69))


def test_answer_length_follows_max_pairs() -> None:
    assert max_answer_chars(64) == 32_800
    assert max_answer_chars(10_000) == 2_020_000


@pytest.mark.parametrize(
    ("replace", "message"),
    [
        ({"object_height: 0.06": "object_height: 0.06\n  max_image_pixels: 0"}, "max_image_pixels"),
        (
            {"travel_speed: 0.15}": "travel_speed: 0.15, max_path_length: -1}"},
            "motion.max_path_length: Input should be greater than 0",
        ),
        (
            {"travel_speed: 0.15}": "travel_speed: 0.15, max_duration_s: .nan}"},
            "motion.max_duration_s",
        ),
        ({"prompt: ": "max_pairs: 10001\n  prompt: "}, "planner.max_pairs: Input should be less"),
    ],
)
def test_bad_bounds_in_a_task_file_are_located_errors(
    replace: dict[str, str], message: str, tmp_path: Path
) -> None:
    with pytest.raises(TaskFileError) as caught:
        keymps.load_task(task_copy(tmp_path, **replace))
    assert message in str(caught.value) and str(caught.value).count("\n") == 0
    assert ":" in str(caught.value).split(" ")[0]  # file:line:col first


# paths on the command line that are not what they claim (found by probing the CLI)


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["validate", "/dev/zero"], "/dev/zero: not a regular file (a device or a pipe)"),
        (["run", "/dev/zero"], "error: /dev/zero: not a regular file"),
        (["run", "{task}", "--out", "{file}", "-q"], "cannot create the run folder: File exists"),
        (["validate", "{big}"], "a task file is at most 1 MB of YAML"),
    ],
    ids=["validate /dev/zero", "run /dev/zero", "--out is a file", "4 GB task file"],
)
def test_cli_paths_that_are_not_what_they_claim(
    args: list[str], expected: str, tmp_path: Path
) -> None:
    """Each was a hang (reading /dev/zero forever) or a raw FileExistsError traceback."""
    from click.testing import CliRunner

    from keymps.cli.app import cli

    task = task_copy(tmp_path / "task")
    taken = tmp_path / "a-file"
    taken.write_text("")
    big = tmp_path / "big.yaml"
    with big.open("wb") as handle:
        handle.truncate(4 * 2**30)  # sparse: no disk used
    filled = [a.format(task=task, file=taken, big=big) for a in args]
    budget = Budget()
    result = CliRunner().invoke(cli, filled)
    budget.check(10.0)
    assert result.exit_code == 1, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(
        result.exception
    )
    assert expected in result.output
    assert "Traceback" not in result.output
