"""A VLM plan whose predicted outcome is wrong goes back for repair, over real HTTP to a local
scripted server (tests/helpers/vlm_server.py), bounded by planner.attempts, every round in vlm/."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.vlm_server import Reply, VlmServer

from keymps import RunOptions, RunOverrides, load_task, run_task
from keymps.config.task import Expect
from keymps.errors import StageError
from keymps.scenes.render import ObjectSpec, SceneSpec, render_scene

KEY_VARIABLE = "OUTCOME_REPAIR_API_KEY"
QUIET = RunOptions(rerun="off", quiet=True)


@pytest.fixture(scope="module")
def cake(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    """A round cake's scene and the exact six-equal-parts pairs in its crop's pixels."""
    folder = tmp_path_factory.mktemp("cake")
    png, _ = render_scene(SceneSpec((ObjectSpec("round_cake", 0.12, 0.12, 0.06, 0.0),))).save(
        folder / "cake.png"
    )
    exact = run_task(
        _task(folder, png, "backend: offline"),
        options=QUIET,
        overrides=RunOverrides(out=folder / "exact"),
        through="ground",
    )
    return png, np.asarray(exact.stages.plan.pairs_crop_px)


def _task(folder: Path, png: Path, planner: str, attempts: int = 2) -> Path:
    path = folder / "task.yaml"
    path.write_text(
        "name: repair\ninstruction: Cut the cake into six equal parts\n"
        f"scene: {{image: {png}, object_height: 0.06}}\n"
        f"planner: {{{planner}, attempts: {attempts}}}\n"
        "primitives: [straight, sawing]\nrobot: {tool: knife}\nheight: {mode: start}\n"
        "executor: {name: sim}\n"
    )
    return path


def _answer(pairs: np.ndarray) -> dict:
    intent = {"pieces": 6, "equal": True, "orientation": None, "slice_width_cm": None,
              "dots": None, "rings": None, "digits": None}  # fmt: skip
    return {"keyword": "straight", "pairs": np.round(pairs, 1).tolist(), "intent": intent,
            "rationale": "six wedges"}  # fmt: skip


def _vlm_task(folder: Path, png: Path, attempts: int = 2) -> Path:
    planner = f"backend: litellm, model: openai/test-vlm, api_key_env: {KEY_VARIABLE}, cache: false"
    return _task(folder, png, planner, attempts)


@pytest.fixture(autouse=True)
def _key(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(KEY_VARIABLE, "sk-test-5e82ab19f0c4d763")


def test_unequal_pieces_go_back_and_the_repaired_plan_runs(cake, tmp_path):
    png, exact = cake
    off_centre = exact + np.array([14.0, 9.0])  # every cut 8 mm from the centre
    with VlmServer() as server:
        server.script(Reply.json_answer(_answer(off_centre)), Reply.json_answer(_answer(exact)))
        run = run_task(
            load_task(_vlm_task(tmp_path, png)),
            options=QUIET,
            overrides=RunOverrides(api_base=server.openai_base, out=tmp_path / "run"),
        )
        requests = server.chat_requests
    assert len(requests) == 2
    repair = requests[1].body["messages"]
    assert repair[-2]["role"] == "assistant" and json.loads(repair[-2]["content"])["pairs"]
    told = repair[-1]["content"]
    assert told.startswith("keymps simulated the motion planned from your answer")
    assert "the cuts leave pieces of" in told and "the intent is 6 equal pieces" in told
    assert run.stages.outcome.verdict == "pass" and run.stages.execute.ok
    assert np.allclose(run.stages.plan.pairs_crop_px, np.round(exact, 1), atol=0.06)
    record = json.loads((run.folder / "run.json").read_text())
    assert record["ok"] and record["vlm"]["calls"] == 2
    rounds = sorted(p.name for p in (run.folder / "vlm").glob("0*.json"))
    assert rounds == ["01-combined-attempt1.json", "02-combined-attempt2.json"]


def test_repair_rounds_are_bounded_by_planner_attempts(cake, tmp_path):
    png, exact = cake
    wrong = exact.copy()
    middle = wrong[0].mean(axis=0)
    turn = np.radians(15.0)  # one cut turned 15 degrees about its middle
    rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    wrong[0] = middle + 0.9 * (wrong[0] - middle) @ rotation.T
    with VlmServer(responder=lambda request: json.dumps(_answer(wrong))) as server:
        with pytest.raises(StageError) as caught:
            run_task(
                load_task(_vlm_task(tmp_path, png, attempts=3)),
                options=QUIET,
                overrides=RunOverrides(api_base=server.openai_base, out=tmp_path / "run"),
            )
        assert len(server.chat_requests) == 3
    message = str(caught.value)
    assert caught.value.stage == "outcome" and "3 plan rounds with the VLM" in message
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["status"] == "failed" and record["execution"] is None
    assert record["outcome"]["intent"][0]["source"] == "answer"


def test_accept_outcome_executes_a_wrong_plan_and_says_so(cake, tmp_path):
    """The expert's override: executed, the verdict recorded as accepted, a warning."""
    png, exact = cake
    off_centre = exact + np.array([14.0, 9.0])
    with VlmServer(responder=lambda request: json.dumps(_answer(off_centre))) as server:
        run = run_task(
            load_task(_vlm_task(tmp_path, png)),
            options=RunOptions(rerun="off", quiet=True, accept_outcome=True),
            overrides=RunOverrides(api_base=server.openai_base, out=tmp_path / "run"),
        )
        assert len(server.chat_requests) == 1  # accepted: no repair round
    record = json.loads((run.folder / "run.json").read_text())
    assert record["ok"] and record["outcome"]["verdict"] == "accepted"
    assert record["outcome"]["accept_outcome"] is True and record["outcome"]["problems"]
    assert any(w.startswith("--accept-outcome: executed although") for w in record["warnings"])


def test_the_offline_planner_is_not_asked_again(tmp_path):
    """Its answer would be the same: a wrong outcome stops at once (here the task's expect:
    asks for 7 pieces of a sentence read as 8)."""
    repo = Path(__file__).resolve().parents[2]
    task = load_task(repo / "tasks" / "object_cutting.yaml")
    task = task.model_copy(update={"expect": Expect(pieces=7, equal=True)})
    with pytest.raises(StageError) as caught:
        run_task(
            task,
            options=QUIET,
            overrides=RunOverrides(backend="offline", out=tmp_path / "run"),
        )
    assert "the cuts leave 8 pieces" in str(caught.value) and "plan rounds" not in str(caught.value)
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["outcome"]["intent"][0]["source"] == "expect"
    assert record["outcome"]["intent"][0]["pieces"] == 7
    assert len(list((tmp_path / "run" / "vlm").glob("0*.json"))) == 1


def _diameters(exact: np.ndarray, count: int) -> np.ndarray:
    """`count` cuts through the centre of the exact plan's cake, equally turned (crop px)."""
    centre = exact.reshape(-1, 2).mean(axis=0)
    radius = float(np.linalg.norm(exact[0, 1] - exact[0, 0])) / 2
    turns = np.pi * np.arange(count) / count
    ends = radius * np.c_[np.cos(turns), np.sin(turns)]
    return np.stack([centre - ends, centre + ends], axis=1)


def test_a_model_that_misreads_the_sentence_is_held_to_the_sentence(cake, tmp_path):
    """A model answering "Cut the cake into six equal parts" with 8 equal wedges, its intent
    claiming 8, was held only to its own claim, and passed. The sentence, as the offline
    grammar reads it, is held against a model's plan too: the 8 pieces go back for repair,
    and the repaired plan (6) runs."""
    png, exact = cake
    eight = {**_answer(_diameters(exact, 4)), "rationale": "eight wedges"}
    eight["intent"] = {**eight["intent"], "pieces": 8}
    with VlmServer() as server:
        server.script(Reply.json_answer(eight), Reply.json_answer(_answer(exact)))
        run = run_task(
            load_task(_vlm_task(tmp_path, png)),
            options=QUIET,
            overrides=RunOverrides(api_base=server.openai_base, out=tmp_path / "run"),
        )
        told = server.chat_requests[1].body["messages"][-1]["content"]
    assert "the cuts leave 8 pieces" in told and "the intent is 6 pieces" in told
    assert run.stages.outcome.verdict == "pass"
    sources = [intent.source for intent in run.stages.outcome.intents]
    assert sources == ["answer", "sentence"]


def test_the_sentence_is_not_held_against_a_task_that_states_expect(cake, tmp_path):
    """`expect:` is the user's own assertion: it alone replaces what the plan claims."""
    png, exact = cake
    eight = {**_answer(_diameters(exact, 4)), "rationale": "eight wedges"}
    eight["intent"] = {**eight["intent"], "pieces": 8}
    task = load_task(_vlm_task(tmp_path, png))
    task = task.model_copy(update={"expect": Expect(pieces=8)})
    with VlmServer(responder=lambda request: json.dumps(eight)) as server:
        run = run_task(
            task,
            options=QUIET,
            overrides=RunOverrides(api_base=server.openai_base, out=tmp_path / "run"),
        )
    assert run.stages.outcome.verdict == "pass"
    assert [intent.source for intent in run.stages.outcome.intents] == ["expect"]
