"""`keymps eval` measures what `keymps run` does: its direct methods perceive through the engine's
own stages (keymps.pipeline.stages), and eval reaches the pipeline through nothing else."""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml

from keymps.eval.context import MethodContext
from keymps.eval.suites import load_suite
from keymps.eval.tasks import case_task_data
from keymps.eval.vlm import look
from keymps.pipeline.engine import run_task
from keymps.run import RunOptions, RunOverrides
from keymps.scenes.perception_cases import BOARD_M, photo_case

EVAL = Path(__file__).resolve().parents[2] / "keymps" / "eval"

STAGE_WORK = {
    "rectify_scene",
    "top_surface",
    "refuse_the_board",
    "crop_covering_objects",
    "scene_objects",
    "make_plan",
}
"""What the image, detect and plan stages do: eval calls the stage API instead."""


def _imports(path: Path) -> list[tuple[str, str]]:
    """(module, name) of every `from module import name` in a file, in functions too."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [
        (node.module or "", alias.name)
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
    ]


def test_eval_reaches_the_pipeline_only_through_run_task_and_the_stage_api() -> None:
    files = sorted(EVAL.glob("*.py"))
    assert len(files) > 10
    for path in files:
        for module, name in _imports(path):
            where = f"{path.name}: from {module} import {name}"
            if module == "keymps.pipeline.engine":
                assert name == "run_task", where
            elif module == "keymps.pipeline":
                assert name == "stages", where
            elif module.startswith("keymps.pipeline."):
                assert module == "keymps.pipeline.stages", where
            assert name not in STAGE_WORK, where


def _context(task: Path, folder: Path) -> MethodContext:
    folder.mkdir(parents=True)
    return MethodContext(task, folder, "litellm", "openai/unused", "http://127.0.0.1:9")


def _same_perception(run_folder: Path, task: Path, direct_folder: Path) -> Any:
    """The engine's image and detect results beside what a direct method sees, compared."""
    run = run_task(
        task,
        options=RunOptions(rerun="off", quiet=True),
        overrides=RunOverrides(out=run_folder),
        through="ground",
    )
    seen = look(_context(task, direct_folder))
    scene, detection = run.stages.image, run.stages.detect
    assert scene is not None and detection is not None
    assert np.array_equal(seen.scene.image, scene.image)
    assert seen.detection.bbox_px == detection.bbox_px
    assert seen.detection.crop_origin_px == detection.crop_origin_px
    assert np.array_equal(seen.detection.crop, detection.crop)
    assert len(seen.detection.objects) == len(detection.objects)
    return seen, run


CASES = [
    ("cutting_sim", 0),
    ("cutting_sim", 1),
    ("icing", 0),
    ("cake_six", 0),
    ("multi_object", 0),
    ("multi_object", 1),
    ("real_cutting", 4),
]


@pytest.mark.parametrize(("suite_name", "index"), CASES)
@pytest.mark.parametrize("seed", [3, 41])
def test_direct_methods_see_the_engines_detection_and_crop(
    tmp_path: Path, suite_name: str, index: int, seed: int
) -> None:
    suite = load_suite(suite_name)
    case = suite.cases[index % len(suite.cases)]
    data = case_task_data(suite, case, seed)
    data["planner"] = {**data.get("planner", {}), "backend": "offline"}
    task = tmp_path / "task.yaml"
    task.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    seen, run = _same_perception(tmp_path / "run", task, tmp_path / "direct")
    assert seen.detection.crop_size_px == run.stages.detect.crop_size_px


@pytest.mark.parametrize("seed", [1, 6])
def test_on_a_photo_direct_methods_see_the_rectified_top_surface(tmp_path: Path, seed: int) -> None:
    """With board corners and intrinsics, the crop is of the rectified image, sides removed."""
    case = photo_case(seed, markers=False)
    cv2.imwrite(str(tmp_path / "photo.png"), case.photo)
    given = case.intrinsics
    data = {
        "name": "photo",
        "instruction": "Put 15 icing dots around the cake, leave space from the edge.",
        "scene": {
            "image": "photo.png",
            "workspace": {"size": list(BOARD_M)},
            "object_height": case.object_height,
            "camera": {
                "board_corners_px": np.round(case.corners_px, 3).tolist(),
                "intrinsics": {k: given[k] for k in ("fx", "fy", "cx", "cy", "distortion")},
            },
        },
        "planner": {"backend": "offline"},
        "primitives": ["line"],
        "robot": {"tool": "piping_bag"},
    }
    task = tmp_path / "task.yaml"
    task.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    seen, _ = _same_perception(tmp_path / "run", task, tmp_path / "direct")
    assert seen.scene.rectification is not None
    assert seen.scene.image.shape[:2] != case.photo.shape[:2]
    assert "top_surface" in seen.detection.report
    board_w, board_h = BOARD_M
    x0, y0, x1, y1 = seen.crop_box_m
    assert 0 <= x0 < x1 <= board_w + 1e-9 and 0 <= y0 < y1 <= board_h + 1e-9
