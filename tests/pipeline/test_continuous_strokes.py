"""Icing lines that meet are piped as one stroke, end to end (issue 39 item 3).

The shipped cake task, the offline planner and the sim executor: the paper's Table IV case 3
("icing dots around the cake and a spiral") is 13 dots and a spiral of 48 pairs that meet end
to end. The spiral must be one work piece, piped without lifting the nozzle, and the sim must
count what was piped: 13 dots and 1 stroke, not a stroke (or a dot) per pair.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from keymps.run import RunOptions, RunOverrides

REPO = Path(__file__).resolve().parents[2]
DOTS_AND_SPIRAL = (
    "Combine 2 types of designs, icing dots around the cake and a spiral icing line design"
)
DRAWING_HEIGHT = 0.06 + 0.005 - 0.004  # top, height.margin, the line primitive's 4 mm dip


def run(instruction: str, out: Path) -> tuple[Any, dict[str, Any]]:
    from keymps import load_task, run_task

    task = load_task(REPO / "tasks" / "cake_icing.yaml")
    done = run_task(task, options=RunOptions(rerun="off", no_cache=True, quiet=True), overrides=RunOverrides(out=out, backend="offline", executor="sim", instruction=instruction))  # fmt: skip
    return done, json.loads((out / "run.json").read_text())


@pytest.fixture(scope="module")
def dots_and_spiral(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, dict[str, Any]]:
    return run(DOTS_AND_SPIRAL, tmp_path_factory.mktemp("spiral"))


def test_the_sim_counts_the_dots_and_one_spiral(dots_and_spiral: tuple[Any, dict]) -> None:
    _, record = dots_and_spiral
    figures = record["execution"]["figures"]
    assert (figures["icing_dots"], figures["icing_strokes"]) == (13, 1)
    assert "1 icing stroke, 13 dots" in record["execution"]["message"]


def test_the_spiral_is_one_work_piece_piped_without_a_lift(
    dots_and_spiral: tuple[Any, dict],
) -> None:
    done, record = dots_and_spiral
    segments = np.array(record["segments_m"])
    lines = np.flatnonzero(np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1) > 0)
    assert len(lines) == 48
    work = [piece["pairs"] for piece in record["pieces"] if piece["kind"] == "work"]
    assert work == [[k] for k in range(13)] + [lines.tolist()]
    assert len(record["pieces"]) == 2 * 14 + 1  # a travel to each stroke, and home
    trajectory = done.stages.time
    spiral = np.flatnonzero(trajectory.piece_index == 2 * 13 + 1)
    z = trajectory.tool_xyz[spiral, 2]
    down = np.flatnonzero(z < DRAWING_HEIGHT + 1e-4)
    # the nozzle goes down once, pipes the whole spiral, and comes up once
    assert np.array_equal(down, np.arange(down[0], down[-1] + 1))
    xy = trajectory.tool_xyz[spiral[down], :2]
    assert np.linalg.norm(xy[0] - segments[13, 0, :2]) < 1e-3
    assert np.linalg.norm(xy[-1] - segments[-1, 1, :2]) < 1e-3
    assert record["trajectory"]["duration_s"] < 0.5 * 129.8  # per-pair pieces took 129.8 s


def test_the_outcome_records_every_pair_the_spiral_pipes(
    dots_and_spiral: tuple[Any, dict],
) -> None:
    """run.json's predicted deposits name all 48 pairs of the spiral's stroke, not its first."""
    _, record = dots_and_spiral
    deposits = record["outcome"]["predicted"]["deposits"]
    work = [piece["pairs"] for piece in record["pieces"] if piece["kind"] == "work"]
    assert [d["pairs"] for d in deposits] == [[k + 1 for k in pairs] for pairs in work]
    assert all(d["pair"] == d["pairs"][0] for d in deposits)
    assert len(deposits[-1]["pairs"]) == 48 and deposits[-1]["kind"] == "line"


@pytest.mark.parametrize(
    ("instruction", "strokes"),
    [
        ("I'm having my 27th birthday, put the digits on the cake as icing lines", 2),
        ("Draw a 5-pointed star using lines in the middle of the cake", 1),
    ],
)
def test_digits_and_stars_are_one_stroke_per_connected_figure(
    instruction: str, strokes: int, tmp_path: Path
) -> None:
    """The 2 of "27" is five segments, its 7 three; the star is five lines tip to tip, listed
    in an order that does not meet end to start: each figure is piped in one stroke."""
    _, record = run(instruction, tmp_path)
    assert record["execution"]["figures"]["icing_strokes"] == strokes
    assert record["execution"]["figures"]["icing_dots"] == 0
    work = [piece["pairs"] for piece in record["pieces"] if piece["kind"] == "work"]
    assert len(work) == strokes
    assert sorted(k for pairs in work for k in pairs) == list(range(len(record["pairs_px"])))
