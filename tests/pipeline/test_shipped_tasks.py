"""Every primitive a shipped task lists works on its own shipped scene (issue 39 item 4).

The pizza of tasks/object_cutting.yaml lay 9 mm from the board's edge: any sawing on it left the
workspace by 3.1 mm ("primitive 'sawing' reaches past the pair's ends"), though the task lists
sawing. Each task runs here once per listed primitive (the task with that primitive alone) with
its own sentence, offline, through the safety check to the file executor.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import keymps
from keymps.config.task import PluginSection
from keymps.run import RunOptions, RunOverrides

REPO = Path(__file__).resolve().parents[2]
TASKS = sorted((REPO / "tasks").glob("*.yaml"))
CASES = [(path, primitive) for path in TASKS for primitive in keymps.load_task(path).primitives]


@pytest.mark.parametrize(
    ("path", "primitive"), CASES, ids=[f"{p.stem}-{primitive}" for p, primitive in CASES]
)
def test_each_listed_primitive_passes_the_safety_check_on_the_shipped_scene(
    path: Path, primitive: str, tmp_path: Path
) -> None:
    task = keymps.load_task(path)
    if task.scene.source == "mujoco":
        pytest.importorskip("mujoco")
    # the task with this primitive alone, its trajectory written to a file (no robot here)
    to_file = PluginSection(name="file")
    alone = task.model_copy(update={"primitives": [primitive], "executor": to_file})
    run = keymps.run_task(
        alone,
        options=RunOptions(rerun="off", quiet=True),
        overrides=RunOverrides(out=tmp_path / "run", backend="offline"),
    )
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["keyword"] == primitive
    assert record["validation"]["verdict"] == "pass"
    assert run.stages.execute is not None


def test_the_shipped_tasks_list_both_cutting_primitives() -> None:
    """The test above covers sawing and straight on the pizza (the issue's case)."""
    assert ("object_cutting", "sawing") in {(p.stem, primitive) for p, primitive in CASES}


def test_saw_it_in_half_saws_the_pizza(tmp_path: Path) -> None:
    """'saw it in half' picked `straight` (the sentence's verb named no primitive)."""
    run = keymps.run_task(
        REPO / "tasks" / "object_cutting.yaml",
        options=RunOptions(rerun="off", quiet=True),
        overrides=RunOverrides(
            instruction="saw it in half", out=tmp_path / "run", backend="offline", executor="file"
        ),
    )
    assert run.stages.plan.keyword == "sawing"
    assert "the sentence names it" in run.stages.plan.rationale


@pytest.mark.parametrize(
    "sentence",
    ["cut into 8 slices, leaving the crust", "Cut it into 8 slices but keep the crust on"],
)
def test_leaving_the_crust_is_refused_before_anything_moves(sentence: str, tmp_path: Path) -> None:
    """It was read as 8 slices (and 'crust' turned the cut into sawing)."""
    with pytest.raises(keymps.KeympsError, match="left uncut"):
        keymps.run_task(
            REPO / "tasks" / "object_cutting.yaml",
            options=RunOptions(rerun="off", quiet=True),
            overrides=RunOverrides(
                instruction=sentence, out=tmp_path / "run", backend="offline", executor="file"
            ),
        )
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record.get("trajectory") in (None, {})
