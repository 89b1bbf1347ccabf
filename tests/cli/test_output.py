"""What `keymps run` prints: a failed run still shows its warnings and run folder; lines are
not cut at 80 columns; counts are singular when they are one."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

import keymps
from keymps.cli.app import cli

REPO = Path(__file__).resolve().parents[2]


def task_file(
    tmp_path: Path, instruction: str, size: str = "[0.30, 0.18]", tool: str = "piping_bag"
) -> Path:
    primitive = "line" if tool == "piping_bag" else "straight"
    height = "both" if tool == "piping_bag" else "start"  # a knife cuts through
    path = tmp_path / "task.yaml"
    path.write_text(
        "name: out\n"
        f"instruction: {instruction}\n"
        "scene:\n"
        f"  image: {REPO / 'tasks' / 'scenes' / 'round_cake.png'}\n"
        f"  workspace: {{size: {size}, shift: [0.0, 0.0]}}\n"
        "  object_height: 0.06\n"
        "planner: {backend: offline}\n"
        f"primitives: [{primitive}]\n"
        f"height: {{mode: {height}}}\n"
        f"robot: {{tool: {tool}}}\n"
        "executor: {name: sim}\n"
    )
    return path


def test_a_failed_run_prints_its_warnings_and_folder_before_the_error(tmp_path: Path) -> None:
    # a board of the wrong shape (a warning), then an instruction the planner refuses (the error)
    path = task_file(tmp_path, "Juggle it please", size="[0.30, 0.30]")
    out = tmp_path / "run"
    result = CliRunner().invoke(cli, ["run", str(path), "--rerun", "off", "--out", str(out)])
    assert result.exit_code == 1
    lines = result.output.splitlines()
    assert any(line.startswith("warning     the image is") for line in lines), result.output
    assert f"run folder  {out}" in lines
    assert lines[-1].startswith("error: plan: the offline planner cannot turn")
    assert (out / "run.json").is_file()


def test_a_failed_quiet_run_prints_its_folder(tmp_path: Path) -> None:
    path = task_file(tmp_path, "Juggle it please")
    out = tmp_path / "run"
    args = ["run", str(path), "--rerun", "off", "--out", str(out), "-q"]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 1
    assert result.output.splitlines()[0] == str(out)


@pytest.mark.parametrize(
    ("instruction", "tool", "made"),
    [
        ("Put 3 icing dots around the cake", "piping_bag", ": 3 dots;"),
        ("Cut it in half", "knife", ": 1 cut;"),
    ],
)
def test_console_lines_are_not_cut_at_80_columns(
    tmp_path: Path, instruction: str, tool: str, made: str
) -> None:
    path = task_file(tmp_path, instruction, tool=tool)
    source = str(Path(keymps.__file__).resolve().parents[1])  # the keymps under test
    env = {**os.environ, "COLUMNS": "80", "TERM": "xterm", "PYTHONPATH": source}
    done = subprocess.run(
        [sys.executable, "-c", "from keymps.cli.app import main; main()", "run", str(path)]
        + ["--rerun", "off"],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    execute = [line for line in done.stderr.splitlines() if "execute" in line]
    assert len(execute) == 1 and len(execute[0]) > 80, done.stderr
    assert "simulated" in execute[0] and made in execute[0] and "max tracking error" in execute[0]
    assert "1 cuts" not in done.stderr and " 0 " not in execute[0]
    starts = ("✓", "backend", "keyword", "segments", "duration", "run folder", "warning", "open")
    for line in (done.stderr + done.stdout).splitlines():
        assert line.startswith(starts), f"a line cut in the middle: {line!r}"


@pytest.mark.parametrize("no_color", [False, True])
def test_progress_is_coloured_on_a_terminal_unless_no_color(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, no_color: bool
) -> None:
    if no_color:
        monkeypatch.setenv("NO_COLOR", "1")
    else:
        monkeypatch.delenv("NO_COLOR", raising=False)
    path = task_file(tmp_path, "Put 3 icing dots around the cake")
    args = ["run", str(path), "--rerun", "off", "--out", str(tmp_path / "run")]
    result = CliRunner().invoke(cli, args, color=True)  # as on a terminal
    assert result.exit_code == 0, result.output
    ticks = [line for line in result.output.splitlines() if "✓" in line]
    assert len(ticks) == 9
    assert all(("\x1b[" in line) is not no_color for line in ticks)


def test_a_cached_answer_is_marked_on_the_console(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Was: the second run of a VLM task printed its plan line like a fresh answer, though no
    model was asked."""
    from helpers.vlm_server import Reply, VlmServer

    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    task = str(REPO / "tasks" / "cake_icing.yaml")
    dot = {"keyword": "line", "pairs": [[[120, 120], [120, 120]]], "rationale": "a dot"}
    with VlmServer() as server:
        server.script(Reply.json_answer(dot))
        arguments = ["run", task, "--model", "openai/test-vlm", "--api-base", server.openai_base]
        first = CliRunner().invoke(
            cli, [*arguments, "--rerun", "off", "--out", str(tmp_path / "a")]
        )
        second = CliRunner().invoke(
            cli, [*arguments, "--rerun", "off", "--out", str(tmp_path / "b")]
        )
        assert first.exit_code == 0 and second.exit_code == 0, first.output + second.output
        asked = len(server.chat_requests)
    assert asked == 1

    def plan_line(stderr: str) -> str:
        return next(line for line in stderr.splitlines() if "plan (keyword" in line)

    assert "cached" not in plan_line(first.stderr)
    assert plan_line(second.stderr).endswith(", cached answer")
