"""The command line: help without heavy imports, exit codes, one-line errors."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from keymps.cli.app import cli

REPO = Path(__file__).resolve().parents[2]
HEAVY = ("litellm", "rerun", "pinocchio", "cv2", "matplotlib", "ruckig", "scipy")


def test_help_lists_commands_without_heavy_imports() -> None:
    code = (
        "import sys\n"
        "from click.testing import CliRunner\n"
        "from keymps.cli.app import cli\n"
        "for args in (['--help'], ['run', '--help'], ['primitives', '--help'], ['scene', '--help']):\n"
        "    result = CliRunner().invoke(cli, args)\n"
        "    assert result.exit_code == 0, (args, result.output)\n"
        "    print(result.output)\n"
        f"heavy = sorted(m for m in sys.modules if m.split('.')[0] in {HEAVY!r})\n"
        "print('HEAVY', heavy)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    assert "HEAVY []" in result.stdout
    for command in ("run", "validate", "plugins", "primitives", "scene"):
        assert f"  {command} " in result.stdout


def test_validate_accepts_shipped_tasks() -> None:
    result = CliRunner().invoke(
        cli,
        ["validate", str(REPO / "tasks/cake_icing.yaml"), str(REPO / "tasks/object_cutting.yaml")],
    )
    assert result.exit_code == 0, result.output
    assert result.output.count("ok: ") == 2


def _broken_task(tmp_path: Path) -> Path:
    (tmp_path / "scene.png").write_bytes(b"")
    path = tmp_path / "broken.yaml"
    path.write_text(
        "name: broken\n"
        "instruction: Cut it into 8 equal slices\n"
        "scene: {image: scene.png}\n"
        "primitives: [straight]\n"
        "motion: {work_speed: -1, clearence: 0.1}\n"
    )
    return path


def test_validate_reports_each_problem_on_one_line_and_exits_1(tmp_path: Path) -> None:
    path = _broken_task(tmp_path)
    result = CliRunner().invoke(cli, ["validate", str(path)])
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert [line.split(": ", 1)[1] for line in lines] == [
        f"scene.image: an empty file (0 bytes), not an image: {tmp_path / 'scene.png'}",
        "motion.work_speed: Input should be greater than 0",
        "motion.clearence: unknown key (did you mean 'clearance'?)",
    ]
    assert lines[0].startswith(f"{path}:3:")
    assert all(line.startswith(f"{path}:5:") for line in lines[1:])


def test_validate_checks_plugin_names_with_their_location(tmp_path: Path) -> None:
    path = REPO / "tasks/cake_icing.yaml"
    task = path.read_text().replace("executor: {name: sim}", "executor: {name: warp-drive}")
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes/round_cake.png").write_bytes(
        (REPO / "tasks/scenes/round_cake.png").read_bytes()
    )
    (tmp_path / "t.yaml").write_text(
        task.replace("../prompts/icing.md", str(REPO / "prompts/icing.md"))
    )
    result = CliRunner().invoke(cli, ["validate", str(tmp_path / "t.yaml")])
    assert result.exit_code == 1
    line_number = task.splitlines().index("executor: {name: warp-drive}") + 1
    assert result.output.startswith(
        f"{tmp_path / 't.yaml'}:{line_number}:11: executor: unknown executor"
    )
    assert "warp-drive" in result.output and "sim" in result.output


def test_run_with_broken_task_is_one_clean_error(tmp_path: Path) -> None:
    result = subprocess.run(
        [
            sys.executable,
            "-c",
            "from keymps.cli import main; main()",
            "run",
            str(_broken_task(tmp_path)),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert result.stderr.startswith("error: broken.yaml:5:")
    assert not (tmp_path / "runs").exists()


def test_usage_errors_exit_2() -> None:
    assert CliRunner().invoke(cli, ["run"]).exit_code == 2
    assert CliRunner().invoke(cli, ["run", "x.yaml", "--rerun", "sometimes"]).exit_code == 2
    assert CliRunner().invoke(cli, ["no-such-command"]).exit_code == 2


def test_version() -> None:
    from keymps import __version__

    result = CliRunner().invoke(cli, ["--version"])
    assert result.exit_code == 0 and __version__ in result.output


@pytest.mark.parametrize(
    "command",
    [
        ["run"],
        ["validate"],
        ["plugins"],
        ["eval"],
        ["calibrate"],
        ["scene", "render"],
        ["primitives", "list"],
        ["primitives", "show"],
        ["primitives", "learn"],
        ["primitives", "plot"],
    ],
)
def test_help_shows_no_empty_bounds(command: list[str]) -> None:
    """Was: `keymps scene render --help` showed `[x<=None]` for an unbounded finite number."""
    done = CliRunner().invoke(cli, [*command, "--help"])
    assert done.exit_code == 0, done.output
    assert "None" not in done.output, done.output


def test_an_image_that_is_no_image_is_refused_before_the_run_folder_is_made(
    tmp_path: Path,
) -> None:
    text = tmp_path / "photo.png"
    text.write_text("not a picture\n")
    out = tmp_path / "run"
    done = CliRunner().invoke(
        cli,
        ["run", str(REPO / "tasks" / "cake_icing.yaml"), "--image", str(text), "--out", str(out)],
    )
    assert done.exit_code == 1
    assert (
        done.stderr.startswith("error: --image: not an image file") and done.stderr.count("\n") == 1
    )
    assert not out.exists()
