"""Several objects with a VLM over real HTTP (tests/helpers/vlm_server.py): the prompt lists the
objects, each returned pair is assigned to the object it lies on, a pair spanning two objects is
sent back for repair and then refused naming both."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.multi_scenes import KNIFE, loaves, scene_file, task_text
from helpers.vlm_server import Reply, VlmServer

from keymps.default_plugins.threshold_detector import ThresholdDetector
from keymps.errors import StageError
from keymps.run import RunOptions, RunOverrides


@pytest.fixture(scope="module")
def server():
    with VlmServer() as running:
        yield running


def _vlm_run(
    server: VlmServer, tmp_path: Path, answer: dict, instruction: str, then: dict | None = None
):
    from keymps import run_task
    from keymps.config.task import load_task

    png, truth = scene_file(tmp_path, loaves(4))
    path = tmp_path / "task.yaml"
    path.write_text(
        task_text(png, instruction, KNIFE).replace(
            "backend: offline",
            "backend: litellm, model: openai/test-vlm, api_key_env: MULTI_TEST_API_KEY, "
            "cache: false",
        )
    )
    server.reset()
    server.script(Reply.json_answer(answer), *([Reply.json_answer(then)] if then else []))
    run = run_task(
        load_task(path),
        options=RunOptions(rerun="off", no_cache=True),
        overrides=RunOverrides(api_base=server.openai_base, out=tmp_path / "run"),
    )
    return run, truth


def _four_loaves(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[dict, tuple[int, int]]:
    """A scene of four loaves, its truth and the detector's crop origin; the test key set."""
    monkeypatch.setenv("MULTI_TEST_API_KEY", "sk-test")
    png, truth = scene_file(tmp_path, loaves(4))
    origin = ThresholdDetector().detect(__import__("cv2").imread(str(png))).crop_origin_px
    return truth, origin


def _crop_px(truth: dict, index: int, fx: float, fy: float, origin: tuple[int, int]) -> list[float]:
    obj = sorted(truth["objects"], key=lambda o: o["bbox_m"][0])[index]
    x0, y0, x1, y1 = obj["bbox_px"]
    return [x0 + fx * (x1 - x0) - origin[0], y0 + fy * (y1 - y0) - origin[1]]


def test_scripted_vlm_pairs_are_assigned_to_the_objects_they_lie_on(
    server: VlmServer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    truth, origin = _four_loaves(tmp_path, monkeypatch)
    # one cut across the right loaf, then two across the left one
    pairs = [
        [_crop_px(truth, 1, -0.05, 0.5, origin), _crop_px(truth, 1, 1.05, 0.5, origin)],
        [_crop_px(truth, 0, -0.05, 0.33, origin), _crop_px(truth, 0, 1.05, 0.33, origin)],
        [_crop_px(truth, 0, -0.05, 0.66, origin), _crop_px(truth, 0, 1.05, 0.66, origin)],
    ]
    answer = {"keyword": "straight", "pairs": pairs, "rationale": "scripted"}
    run, truth = _vlm_run(
        server, tmp_path, answer, "Cut the left one into 3 and the right one in half"
    )
    (request,) = server.chat_requests
    assert request.headers["authorization"] == "Bearer sk-test"
    text = json.dumps(request.body["messages"])
    assert "The image shows 2 objects" in text and "object 1:" in text and "object 2:" in text
    plan = run.stages.plan
    # visited object by object: the left loaf (nearer the base) first, its cuts in the given order
    assert list(plan.pair_objects) == [1, 1, 2]
    assert np.allclose(plan.pairs_crop_px, np.array(pairs, float)[[1, 2, 0]])
    assert run.stages.check.report.ok and run.stages.execute.figures["cuts"] == 3


def test_a_vlm_cut_spanning_two_objects_is_refused_naming_both(
    server: VlmServer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    truth, origin = _four_loaves(tmp_path, monkeypatch)
    across = [[_crop_px(truth, 0, 0.2, 0.5, origin), _crop_px(truth, 1, 0.8, 0.5, origin)]]
    spanning = {"keyword": "straight", "pairs": across, "rationale": "x"}
    with pytest.raises(StageError, match=r"^plan: .*pair 1 .* spans objects #1 and #2"):
        _vlm_run(server, tmp_path, spanning, "Cut both", then=spanning)
    # the problem went back to the model for repair before the plan was refused
    assert len(server.chat_requests) == 2
    assert "spans objects #1 and #2" in json.dumps(server.chat_requests[1].body["messages"])
    assert not (tmp_path / "run" / "trajectory.csv").exists()


def test_a_spanning_pair_is_repaired_by_the_model(
    server: VlmServer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    truth, origin = _four_loaves(tmp_path, monkeypatch)
    across = [[_crop_px(truth, 0, 0.2, 0.5, origin), _crop_px(truth, 1, 0.8, 0.5, origin)]]
    fixed = [
        [_crop_px(truth, 0, -0.05, 0.5, origin), _crop_px(truth, 0, 1.05, 0.5, origin)],
        [_crop_px(truth, 1, -0.05, 0.5, origin), _crop_px(truth, 1, 1.05, 0.5, origin)],
    ]
    run, _ = _vlm_run(
        server, tmp_path, {"keyword": "straight", "pairs": across, "rationale": "x"},
        "Cut each of them in half", then={"keyword": "straight", "pairs": fixed, "rationale": "y"},
    )  # fmt: skip
    assert list(run.stages.plan.pair_objects) == [1, 2] and run.stages.check.report.ok


def test_a_named_design_is_laid_out_on_the_object_it_names(
    server: VlmServer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MULTI_TEST_API_KEY", "sk-test")
    design = {"name": "equal", "count": 3, "object": 2}
    answer = {"keyword": "straight", "pairs": None, "design": design, "rationale": "x"}
    run, truth = _vlm_run(server, tmp_path, answer, "Cut the right one into 3")
    plan = run.stages.plan
    assert list(plan.pair_objects) == [2, 2] and plan.design is not None
    right = sorted(truth["objects"], key=lambda o: o["bbox_m"][0])[1]
    x0, _, x1, _ = right["bbox_m"]
    for segment in run.stages.ground.segments_m:
        assert x0 - 0.002 <= segment[:, 0].min() and segment[:, 0].max() <= x1 + 0.002
    assert run.stages.check.report.ok


def test_a_named_design_without_its_object_is_refused(
    server: VlmServer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MULTI_TEST_API_KEY", "sk-test")
    answer = {"keyword": "straight", "pairs": None, "design": {"name": "equal", "count": 3}}
    with pytest.raises(StageError, match=r"does not say which of the 2 objects it is for"):
        _vlm_run(server, tmp_path, answer, "Cut the right one into 3")
