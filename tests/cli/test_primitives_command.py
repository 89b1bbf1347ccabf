"""`keymps primitives` list / show / learn / plot, through click's runner."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from keymps.cli.primitives import primitives
from keymps.primitives.demos import load_demo_csv, write_demo_csv
from keymps.primitives.dictionary import BUNDLED_DIR, load_primitive


@pytest.fixture
def runner(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> CliRunner:
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("KEYMPS_PRIMITIVES_PATH", raising=False)
    return CliRunner()


def test_list_shows_the_bundled_dictionary(runner: CliRunner) -> None:
    result = runner.invoke(primitives, ["list"])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0].split()[:3] == ["NAME", "FAMILY", "MODE"]
    names = [line.split()[0] for line in lines[1:]]
    assert names == ["downward", "forward", "line", "sawing", "straight"]
    assert "icing" in lines[3] and "axial" in lines[3]


def test_show_prints_what_the_planner_reads(runner: CliRunner) -> None:
    result = runner.invoke(primitives, ["show", "sawing"])
    assert result.exit_code == 0, result.output
    assert "Sawing cut" in result.output
    assert "50 basis functions" in result.output
    assert "sawing.csv (501 samples)" in result.output
    assert re.search(r"fit RMSE: +0\.0\d{3} mm", result.output)


def test_unknown_name_is_one_error_line(runner: CliRunner) -> None:
    result = runner.invoke(primitives, ["show", "chop"])
    assert result.exit_code == 1
    assert result.output.startswith("error: unknown primitive 'chop'; available: downward")
    assert len(result.output.strip().splitlines()) == 1


def test_learn_writes_a_primitive_that_list_and_show_find(
    runner: CliRunner, tmp_path: Path
) -> None:
    t, y = load_demo_csv(BUNDLED_DIR / "forward.csv")
    write_demo_csv(tmp_path / "push.csv", t, y + [0.1, 0.2, 0.0])
    result = runner.invoke(
        primitives,
        ["learn", "push.csv", "--name", "push", "--basis", "30", "--description", "Push it.",
         "--speed", "0.025", "--out", "mine"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "wrote mine/push.yaml: 30 basis functions" in result.output
    primitive = load_primitive(tmp_path / "mine" / "push.yaml")
    assert primitive.description == "Push it."
    assert primitive.nominal_speed == 0.025
    assert primitive.mode == "blade"  # the default for a cutting demo
    assert primitive.fit_rmse < 0.0005
    assert (tmp_path / "mine" / "push.csv").is_file()
    listed = runner.invoke(primitives, ["list", "--dir", "mine"])
    assert "push" in listed.output
    shown = runner.invoke(primitives, ["show", "push", "--dir", "mine"])
    assert "learned from:  push.csv" in shown.output


def test_a_flat_cutting_log_is_learned_as_axial_and_stays_on_its_segment(
    runner: CliRunner, tmp_path: Path
) -> None:
    """A logged slicing stroke along the board: 8 cm along x, its height drifting 0.07 mm with
    sensor noise. blade would divide by that drift; learn picks axial and says why."""
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.006, 0.010, 600))
    x = np.clip((t - t[0] - 0.5) / 3.0, 0.0, 1.0)
    y = np.stack([0.3 + 0.08 * x, 0.2 + 0.01 * np.sin(4 * np.pi * x), 0.1 - 7e-5 * x], axis=1)
    write_demo_csv(tmp_path / "slice.csv", t, y + rng.normal(0.0, 5e-5, y.shape))
    result = runner.invoke(primitives, ["learn", "slice.csv", "--name", "slice"])
    assert result.exit_code == 0, result.output
    assert "mode axial" in result.output
    assert "so it re-targets as axial" in result.output
    primitive = load_primitive(tmp_path / "primitives" / "slice.yaml")
    assert primitive.mode == "axial"
    start = primitive.dmp.demo_start
    goal = start + np.array([0.1, 0.05, 0.0])
    path = primitive.dmp.rollout(start, goal, mode=primitive.mode).y
    # Within the demo's own 1 cm wave of the straight line start -> goal.
    direction = (goal - start) / np.linalg.norm(goal - start)
    offsets = (path - start) - np.outer((path - start) @ direction, direction)
    assert np.linalg.norm(offsets, axis=1).max() < 0.012
    assert np.linalg.norm(path[-1] - goal) < 1e-4
    # Asked for blade anyway: kept as asked, and show tells how it behaves.
    forced = runner.invoke(primitives, ["learn", "slice.csv", "--name", "hard", "--mode", "blade"])
    assert "mode blade" in forced.output and "so it re-targets as axial" in forced.output
    shown = runner.invoke(primitives, ["show", "hard"])
    assert "mode:          blade (re-targets as axial: the demo moves only" in shown.output


def test_learn_from_a_bad_csv_is_one_error_line(runner: CliRunner, tmp_path: Path) -> None:
    (tmp_path / "log.csv").write_text("time,x,y,z\n0,0,0,0\n")
    result = runner.invoke(primitives, ["learn", "log.csv", "--name", "x"])
    assert result.exit_code == 1
    assert result.output.strip() == (
        "error: log.csv:1: expected columns t,x,y,z (seconds, metres), got time,x,y,z"
    )


def test_plot_draws_time_coloured_rollouts(runner: CliRunner, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    result = runner.invoke(
        primitives, ["plot", "sawing", "--to", "0.0,0.1,0.0", "--to", "0.15,0,0", "--out", "s.png"]
    )
    assert result.exit_code == 0, result.output
    import matplotlib.image

    image = matplotlib.image.imread(tmp_path / "s.png")[..., :3]
    red = ((image[..., 0] > 0.8) & (image[..., 1] < 0.3) & (image[..., 2] < 0.3)).sum()
    green = ((image[..., 1] > 0.8) & (image[..., 0] < 0.3) & (image[..., 2] < 0.3)).sum()
    blue = ((image[..., 2] > 0.8) & (image[..., 0] < 0.3) & (image[..., 1] < 0.3)).sum()
    assert min(red, green, blue) > 20


def test_plot_without_matplotlib_says_how_to_get_it(
    runner: CliRunner, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    result = runner.invoke(primitives, ["plot", "line"])
    assert result.exit_code == 1
    assert "plot needs matplotlib: pip install matplotlib" in result.output


def test_bad_point_is_a_usage_error(runner: CliRunner) -> None:
    result = runner.invoke(primitives, ["plot", "line", "--to", "1,2"])
    assert result.exit_code == 2
    assert "not three finite numbers" in result.output


def test_module_imports_only_click_at_top() -> None:
    source = Path(sys.modules["keymps.cli.primitives"].__file__ or "").read_text()
    top_imports = [line for line in source.splitlines() if line.startswith(("import ", "from "))]
    allowed = {"__future__", "sys", "math", "collections.abc", "pathlib", "typing", "click"}
    allowed |= {"keymps.cli.errors"}
    assert {line.split()[1] for line in top_imports} <= allowed


@pytest.mark.parametrize(
    "arguments",
    [
        ["--to", "nan,0,0"],
        ["--to", "0,inf,0"],
        ["--from", "-inf,0,0"],
        ["--from", "0,0,nan", "--to", "0.1,0,0"],
    ],
)
def test_plot_refuses_a_point_that_is_not_finite(runner: CliRunner, arguments: list[str]) -> None:
    """nan once recursed in the re-targeting until Python gave up (a RecursionError traceback)."""
    result = runner.invoke(primitives, ["plot", "line", *arguments, "--out", "p.png"])
    assert result.exit_code == 2, result.output
    assert "is not three finite numbers A,B,C (metres)" in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)


def test_plot_refuses_a_format_matplotlib_cannot_write_before_drawing(
    runner: CliRunner, tmp_path: Path
) -> None:
    pytest.importorskip("matplotlib")
    result = runner.invoke(primitives, ["plot", "line", "--out", "p.txt"])
    assert result.exit_code == 2, result.output
    assert "p.txt: matplotlib writes no .txt files (one of: " in result.output
    assert "png" in result.output and not (tmp_path / "p.txt").exists()
    written = runner.invoke(primitives, ["plot", "line", "--out", "p.svg"])
    assert written.exit_code == 0, written.output
    assert (tmp_path / "p.svg").read_text().lstrip().startswith("<?xml")


def test_a_rollout_to_a_point_that_is_not_finite_is_a_dmp_error() -> None:
    from keymps.primitives.system import DmpError

    line = load_primitive(BUNDLED_DIR / "line.yaml")
    for goal in ([np.nan, 0, 0], [0, np.inf, 0], [0.1, 0.0]):
        with pytest.raises(DmpError, match="goal must be a finite"):
            line.rollout([0, 0, 0], goal)
        with pytest.raises(DmpError, match="goal must be a finite"):
            line.dmp.path_length(np.zeros(3), np.asarray(goal, float))
