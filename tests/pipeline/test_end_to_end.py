"""Both shipped tasks, run offline through the command line, leave a complete run folder."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from keymps.cli.app import cli

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("runs")
    folders = {}
    for task in ("cake_icing", "object_cutting"):
        folder = out / task
        result = CliRunner().invoke(
            cli,
            ["run", str(REPO / f"tasks/{task}.yaml"), "--out", str(folder), "--no-cache"],
            env={"OPENAI_API_KEY": None},
        )
        assert result.exit_code == 0, result.output
        assert "run folder" in result.output
        folders[task] = folder
    return folders


def _record(folder: Path) -> dict:
    return json.loads((folder / "run.json").read_text())


@pytest.mark.parametrize("task", ["cake_icing", "object_cutting"])
def test_run_folder_is_complete(runs: dict[str, Path], task: str) -> None:
    folder = runs[task]
    for name in ("run.json", "plan.png", "plan_outcome.png", "outcome.png", "trajectory.csv"):
        assert (folder / name).stat().st_size > 0, name
    assert (folder / "run.rrd").stat().st_size > 0
    record = _record(folder)
    assert record["schema_version"] == "1.7"
    listed = {p.name + ("/" if p.is_dir() else "") for p in folder.iterdir()}
    assert record["files"] == sorted(listed - {"run.json", "vlm/", ".keymps.lock"})
    assert record["outcome"]["verdict"] == "pass" and record["outcome"]["problems"] == []
    assert record["ok"] is True and record["error"] is None
    assert record["backend"] == "offline"
    assert record["validation"]["verdict"] == "pass"
    assert set(record["timings_s"]) == {
        "image",
        "detect",
        "plan",
        "ground",
        "compose",
        "solve",
        "time",
        "check",
        "outcome",
        "execute",
    }
    x0, y0, x1, y1 = record["detection"]["bbox_px"]
    width, height = record["image"]["size_px"]
    assert 0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height
    pairs = np.array(record["pairs_px"])
    assert pairs.shape[1:] == (2, 2)
    assert (pairs[..., 0] >= x0 - 1).all() and (pairs[..., 0] <= x1 + 1).all()
    segments = np.array(record["segments_m"])
    assert segments.shape == (len(pairs), 2, 3)


def test_trajectory_csv_matches_run_json(runs: dict[str, Path]) -> None:
    for folder in runs.values():
        with (folder / "trajectory.csv").open() as handle:
            rows = list(csv.reader(handle))
        assert rows[0] == ["t", "q1", "q2", "q3", "q4", "q5", "q6", "x", "y", "z", "piece", "kind"]
        record = _record(folder)
        assert len(rows) - 1 == record["trajectory"]["samples"]
        t = np.array([float(r[0]) for r in rows[1:]])
        assert np.allclose(np.diff(t), 1 / record["trajectory"]["rate_hz"], atol=1e-6)
        assert abs(t[-1] - record["trajectory"]["duration_s"]) < 1e-3
        assert {r[11] for r in rows[1:]} == {"work", "travel"}
        pieces = record["pieces"]  # the csv's piece column indexes run.json's pieces
        assert all(pieces[int(r[10])]["kind"] == r[11] for r in rows[1:])
        piped = sorted(k for piece in pieces if piece["kind"] == "work" for k in piece["pairs"])
        assert piped == list(range(len(record["pairs_px"])))  # every pair, once
        z = np.array([float(r[9]) for r in rows[1:]])
        assert z.min() >= -0.0005


def test_icing_plan_is_fifteen_dots_on_the_top_surface(runs: dict[str, Path]) -> None:
    record = _record(runs["cake_icing"])
    assert record["keyword"] == "line"
    segments = np.array(record["segments_m"])
    assert len(segments) == 15
    assert np.allclose(segments[:, 0], segments[:, 1], atol=1e-9)  # dots: start = goal
    assert np.allclose(segments[..., 2], 0.06 + 0.005)


def test_cutting_plan_cuts_from_above_the_top_down_to_the_board(runs: dict[str, Path]) -> None:
    record = _record(runs["object_cutting"])
    assert record["keyword"] in ("straight", "sawing")
    segments = np.array(record["segments_m"])
    assert np.allclose(segments[:, 0, 2], 0.02 + 0.005)
    assert np.allclose(segments[:, 1, 2], 0.0)
