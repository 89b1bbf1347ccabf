"""Issue 36's runs, tried as a new user would: each reported ok: true with nothing right.

Each now ends not ok at the outcome stage with a one-line reason, nothing executed (or, the
turned cake, is planned right: three equal pieces). The MuJoCo run is in
plugins/keymps-mujoco/tests/test_mujoco.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.vlm_server import Reply, VlmServer

from keymps import RunOptions, RunOverrides, load_task, run_task
from keymps.errors import StageError
from keymps.outcome.pieces import check_equal_parts
from keymps.scenes.render import ObjectSpec, SceneSpec, render_scene

KNIFE = "primitives: [straight, sawing]\nrobot: {tool: knife}\nheight: {mode: start}\n"
ICING = "primitives: [line]\nrobot: {tool: piping_bag}\nheight: {mode: both}\n"
QUIET = RunOptions(rerun="off", quiet=True)


def _scene(tmp_path: Path, obj: ObjectSpec, seed: int = 1) -> tuple[Path, dict]:
    rendered = render_scene(SceneSpec((obj,), seed=seed))
    png, _ = rendered.save(tmp_path / "scene.png")
    return png, rendered.truth


def _task(
    tmp_path: Path, png: Path, sentence: str, tools: str, height: float, planner: str = ""
) -> Path:
    path = tmp_path / "task.yaml"
    path.write_text(
        f"name: issue36\ninstruction: {sentence}\n"
        f"scene: {{image: {png}, object_height: {height}}}\n"
        f"planner: {{{planner or 'backend: offline'}}}\n{tools}executor: {{name: sim}}\n"
    )
    return path


def _refused(task: Path, out: Path, api_base: str | None = None) -> tuple[StageError, dict]:
    """The run's outcome error and its run.json; nothing after the outcome stage ran."""
    with pytest.raises(StageError) as caught:
        run_task(load_task(task), options=QUIET, overrides=RunOverrides(out=out, api_base=api_base))
    error = caught.value
    record = json.loads((out / "run.json").read_text())
    assert error.stage == "outcome" and "\n" not in str(error)
    assert record["status"] == "failed" and record["error"] == str(error)
    assert record["outcome"]["verdict"] == "fail" and record["outcome"]["problems"]
    assert record["execution"] is None and not (out / "trajectory.csv").exists()
    assert (out / "plan_outcome.png").stat().st_size > 0
    return error, record


def test_a_turned_square_cake_cut_vertically_into_3_is_refused_or_cut_right(tmp_path):
    """Turned 10 degrees: image-vertical cuts left 44-57 cm² pieces with "3 equal parts"."""
    png, truth = _scene(tmp_path, ObjectSpec("square_cake", 0.12, 0.12, 0.06, 10.0))
    task = _task(tmp_path, png, "Cut it vertically into 3 slices", KNIFE, 0.06)
    out = tmp_path / "run"
    try:
        run = run_task(load_task(task), options=QUIET, overrides=RunOverrides(out=out))
    except StageError as error:
        assert error.stage == "outcome" and "\n" not in str(error)
        assert "vertical" in str(error) or "equal" in str(error)
        return
    # planned right: the cuts leave three equal pieces of the cake's true outline
    lines = run.stages.ground.segments_m[:, :, :2]
    check = check_equal_parts(np.array(truth["objects"][0]["outline_m"]), lines, 3, 0.05)
    assert check.ok, check.describe()
    assert run.stages.outcome.verdict == "pass"


def test_a_vlm_pair_beside_the_potato_cuts_nothing_and_is_refused(tmp_path, monkeypatch):
    """The only pair lies in the corner of the crop beside the potato, within the safety
    check's footprint + 2 cm: the simulator said "1 cut" of 0.0 mm. The repair round gets the
    same answer: still refused, after planner.attempts (2) rounds."""
    monkeypatch.setenv("OUTCOME_TEST_API_KEY", "sk-test-9d41c07be2f58a36")
    png, _ = _scene(tmp_path, ObjectSpec("potato", 0.09, 0.06, 0.05, 0.0), seed=2)
    planner = "backend: litellm, model: openai/test-vlm, api_key_env: OUTCOME_TEST_API_KEY, "
    task = _task(tmp_path, png, "Cut the potato in half", KNIFE, 0.05, planner + "cache: false")
    corner = {"keyword": "straight", "pairs": [[[12, 12], [50, 12]]], "intent": None,
              "rationale": "a cut"}  # fmt: skip
    with VlmServer() as server:
        server.script(Reply.json_answer(corner), Reply.json_answer(corner))
        error, record = _refused(task, tmp_path / "run", api_base=server.openai_base)
        assert len(server.chat_requests) == 2
    assert "cut 1 misses the food" in str(error)
    assert record["outcome"]["predicted"]["cuts"][0]["length_m"] == 0.0
    assert len(list((tmp_path / "run" / "vlm").glob("*-combined-attempt*.json"))) == 2


def test_a_knife_task_on_an_object_of_no_height_cuts_nothing(tmp_path):
    """object_height: 0.0 was reported as "4 icing strokes"."""
    png, _ = _scene(tmp_path, ObjectSpec("round_pizza", 0.15, 0.15, 0.02, 0.0))
    # the UR3 5 cm back from its default base: there its upper arm comes near wrist 1 over the
    # far rim, and the self-contact check (not this test's subject) would refuse the run first
    back = KNIFE.replace("{tool: knife}", "{tool: knife, base: [0.15, -0.25, 0.0, 90]}")
    task = _task(tmp_path, png, "Cut it into 8 equal slices", back, 0.0)
    error, record = _refused(task, tmp_path / "run")
    assert "never goes below the object's top, 0.0 mm above the board" in str(error)
    assert all(c["length_m"] == 0 for c in record["outcome"]["predicted"]["cuts"])


def test_forty_dots_around_an_11_cm_cake_merge_into_a_ring(tmp_path):
    """40 dots 6.7 mm apart: dots 8 mm across (twice the 4 mm line) run into one ring."""
    png, _ = _scene(tmp_path, ObjectSpec("round_cake", 0.11, 0.11, 0.06, 0.0))
    task = _task(tmp_path, png, "Put 40 dots around the cake", ICING, 0.06)
    error, record = _refused(task, tmp_path / "run")
    assert "the icing merges: dots of pairs" in str(error) and "need 8.0 mm" in str(error)
    deposits = record["outcome"]["predicted"]["deposits"]
    assert len(deposits) == 40 and all(d["kind"] == "dot" and d["on_top"] for d in deposits)
    # the same sentence with 20 dots (13.4 mm apart) is fine
    task = _task(tmp_path, png, "Put 20 dots around the cake", ICING, 0.06)
    run = run_task(load_task(task), options=QUIET, overrides=RunOverrides(out=tmp_path / "twenty"))
    assert run.stages.outcome.verdict == "pass" and run.stages.execute.ok


def test_the_shipped_cutting_task_cuts_every_line_through_in_the_sim(tmp_path):
    """The sim executor's cuts, with the blade where the wrist turns it, are the predicted
    ones: none stops short (the modulo-180 yaw left the first fifth of some uncut)."""
    repo = Path(__file__).resolve().parents[2]
    run = run_task(
        repo / "tasks" / "object_cutting.yaml",
        options=QUIET,
        overrides=RunOverrides(backend="offline", out=tmp_path / "run"),
    )
    predicted, measured = run.stages.outcome.predicted, run.stages.execute.measured
    assert measured is not None and len(measured.cuts) == len(predicted.cuts) == 4
    for cut, made in zip(predicted.cuts, measured.cuts, strict=True):
        assert made.length_m >= 0.98 * cut.length_m and cut.length_m >= 0.98 * cut.chord_m
    assert [round(p.share, 2) for p in predicted.pieces] == pytest.approx([0.125] * 8, abs=0.01)
