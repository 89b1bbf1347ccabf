"""The litellm backend over real HTTP to a local OpenAI-compatible / Ollama-style server."""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
from helpers.synthetic_crops import CUTTING, make_scene, plan_for
from helpers.vlm_server import Reply, VlmServer

from keymps.errors import KeympsError
from keymps.run import RunOptions, RunOverrides

CANARY = "sk-canary-7f3e9b2d1c4a"
GOOD = {
    "keyword": "straight",
    "pairs": [[[20, 30], [200, 210]], [[15, 120], [230, 120]]],
    "rationale": "two cuts",
}


@pytest.fixture(scope="module")
def server():
    with VlmServer(responder=lambda request: json.dumps(GOOD)) as running:
        yield running


@pytest.fixture(autouse=True)
def _isolated(server, monkeypatch, tmp_path):
    server.reset()
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("KEYMPS_TEST_VLM_KEY", CANARY)


@pytest.fixture(scope="module")
def scene():
    return make_scene("disk", (200, 200))


def _plan(server, scene, tmp_path, model="openai/test-vlm", **planner):
    planner.setdefault("api_base", server.openai_base if model.startswith("openai") else server.url)
    planner.setdefault("api_key_env", "KEYMPS_TEST_VLM_KEY")
    planner.setdefault("cache", False)
    return plan_for(
        "Cut it into 8 equal slices",
        scene,
        CUTTING,
        backend="litellm",
        folder=tmp_path / "run",
        model=model,
        **planner,
    )


def _decode_png(data: str) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)


def test_openai_compatible_server_gets_the_crop_and_schema(server, scene, tmp_path):
    plan, run = _plan(server, scene, tmp_path)
    (request,) = server.chat_requests
    assert request.path == "/v1/chat/completions"
    assert request.headers["authorization"] == f"Bearer {CANARY}"
    body = request.body
    assert body["model"] == "test-vlm" and body["temperature"] == 0.0
    image = body["messages"][1]["content"][1]["image_url"]["url"]
    assert image.startswith("data:image/png;base64,")
    assert np.array_equal(_decode_png(image.split(",", 1)[1]), scene.detection.crop)
    schema = body["response_format"]["json_schema"]["schema"]
    assert body["response_format"]["type"] == "json_schema"
    assert schema["properties"]["keyword"]["enum"] == ["straight", "sawing"]
    assert "Cut it into 8 equal slices" in json.dumps(body["messages"])
    # the answer became the plan, in full-image pixels
    assert plan.keyword == "straight" and plan.model == "openai/test-vlm"
    expected = np.array(GOOD["pairs"], float) + np.array(scene.detection.crop_origin_px)
    assert np.allclose(plan.pairs_px, expected)
    (call,) = plan.calls
    assert (call.prompt_tokens, call.completion_tokens) == (321, 45)
    assert call.cost_usd == 0.0 and call.latency_s > 0 and not call.cached
    recorded = json.loads(next((run.folder / "vlm").glob("01-*.json")).read_text())
    assert recorded["answer"] == json.dumps(GOOD) and recorded["valid"]
    assert "sha256:" in json.dumps(recorded["request"]["messages"])
    assert (run.folder / "vlm" / "crop.png").is_file()


@pytest.mark.parametrize(
    ("model", "path"), [("ollama/llava", "/api/generate"), ("ollama_chat/llava", "/api/chat")]
)
def test_ollama_style_endpoint(server, scene, tmp_path, model, path):
    plan, _ = _plan(server, scene, tmp_path, model=model, api_key_env=None)
    (request,) = server.chat_requests
    assert request.path == path
    body = request.body
    images = body["images"] if "images" in body else body["messages"][1]["images"]
    assert np.array_equal(_decode_png(images[0]), scene.detection.crop)
    assert body["format"]["properties"]["keyword"]["enum"] == ["straight", "sawing"]
    assert plan.keyword == "straight" and plan.num_pairs == 2


def test_malformed_then_good_answer_is_repaired(server, scene, tmp_path):
    server.script(Reply.text_answer("Sure! Here are the cuts: [[1, 2]"), Reply.json_answer(GOOD))
    plan, run = _plan(server, scene, tmp_path)
    assert [c.error is None for c in plan.calls] == [False, True]
    repair = server.chat_requests[1].body["messages"]
    assert repair[-2] == {"role": "assistant", "content": "Sure! Here are the cuts: [[1, 2]"}
    assert "not a JSON object" in repair[-1]["content"]
    assert len(list((run.folder / "vlm").glob("*-combined-attempt*.json"))) == 2


def test_json_in_code_fences_and_prose_is_accepted(server, scene, tmp_path):
    server.script(Reply.text_answer("Here you go:\n```json\n" + json.dumps(GOOD) + "\n```\nEnjoy"))
    plan, _ = _plan(server, scene, tmp_path)
    assert len(plan.calls) == 1 and plan.num_pairs == 2


@pytest.mark.parametrize(
    ("answer", "words"),
    [
        ("I cannot help with that.", "not a JSON object"),
        (json.dumps({**GOOD, "keyword": "chop"}), "'chop' is not one of: straight, sawing"),
        (json.dumps({**GOOD, "pairs": [[[10, 10], [9999, 10]]]}), "outside the image"),
        (json.dumps({**GOOD, "pairs": []}), "0 pairs given"),
    ],
)
def test_persistently_invalid_answers_stop_the_plan(server, scene, tmp_path, answer, words):
    server.script(Reply.text_answer(answer), Reply.text_answer(answer))
    with pytest.raises(KeympsError) as error:
        _plan(server, scene, tmp_path)
    message = str(error.value)
    assert words in message and "2 attempt(s)" in message and "\n" not in message
    assert len(server.chat_requests) == 2
    files = sorted((tmp_path / "run" / "vlm").glob("*-attempt*.json"))
    assert [json.loads(f.read_text())["valid"] for f in files] == [False, False]


def test_rate_limit_is_retried_after_the_servers_delay(server, scene, tmp_path):
    server.script(Reply.error(429, retry_after=1))
    started = time.perf_counter()
    plan, _ = _plan(server, scene, tmp_path)
    assert time.perf_counter() - started >= 1.0
    assert len(server.chat_requests) == 2 and plan.num_pairs == 2


def test_server_errors_are_retried_then_reported(server, scene, tmp_path):
    server.script(Reply.error(500), Reply.error(503, retry_after=0))
    started = time.perf_counter()
    plan, _ = _plan(server, scene, tmp_path)
    assert 1.0 <= time.perf_counter() - started < 5.0  # 1 s backoff, then Retry-After: 0
    assert len(server.chat_requests) == 3 and plan.keyword == "straight"
    server.reset()
    server.script(*[Reply.error(503, retry_after=0)] * 5)
    with pytest.raises(KeympsError, match="failed after 4 tries"):
        _plan(server, scene, tmp_path)


def test_truncated_answer_is_retried(server, scene, tmp_path):
    server.script(Reply.truncated())
    plan, _ = _plan(server, scene, tmp_path)
    assert plan.num_pairs == 2 and len(server.chat_requests) == 2


def test_timeout_is_a_clean_error(server, scene, tmp_path):
    server.script(Reply.text_answer(json.dumps(GOOD), delay_s=2.0))
    with pytest.raises(KeympsError, match=r"no answer within 0.5 s \(planner.timeout_s\)"):
        _plan(server, scene, tmp_path, timeout_s=0.5)


def test_two_calls_keyword_then_pairs(server, scene, tmp_path):
    server.script(
        Reply.json_answer({"keyword": "sawing", "rationale": "crusty"}),
        Reply.json_answer({"pairs": GOOD["pairs"], "rationale": "two cuts"}),
    )
    plan, _ = _plan(server, scene, tmp_path, combined=False)
    first, second = (r.body for r in server.chat_requests)
    assert set(first["response_format"]["json_schema"]["schema"]["properties"]) == {
        "keyword",
        "rationale",
    }
    assert set(second["response_format"]["json_schema"]["schema"]["properties"]) == {
        "pairs",
        "design",
        "intent",
        "rationale",
    }  # planner.answer: either (pairs or a named design, and what the pairs achieve)
    assert "The chosen primitive is: sawing" in json.dumps(second["messages"])
    assert plan.keyword == "sawing" and plan.num_pairs == 2 and len(plan.calls) == 2


def test_missing_key_variable_is_named(server, scene, tmp_path, monkeypatch):
    monkeypatch.delenv("KEYMPS_TEST_VLM_KEY")
    with pytest.raises(KeympsError, match=r"\$KEYMPS_TEST_VLM_KEY, which is not set"):
        _plan(server, scene, tmp_path)


def test_canary_key_never_reaches_a_file(server, scene, tmp_path):
    server.script(Reply.text_answer("garbage"))
    cassette = tmp_path / "cassette.jsonl"
    plan_for(
        "Cut it into 8 equal slices",
        scene,
        CUTTING,
        backend="litellm",
        folder=tmp_path / "run",
        options=RunOptions(record=cassette),
        model="openai/test-vlm",
        api_base=server.openai_base,
        api_key_env="KEYMPS_TEST_VLM_KEY",
    )
    assert all(r.headers["authorization"] == f"Bearer {CANARY}" for r in server.chat_requests)
    written = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert cassette in written and any(p.suffix == ".json" for p in written)
    for path in written:
        assert CANARY.encode() not in path.read_bytes(), path


# --- through the whole pipeline --------------------------------------------------------------

REPO = __import__("pathlib").Path(__file__).resolve().parents[2]
CUTTING_TASK = REPO / "tasks" / "object_cutting.yaml"


@pytest.mark.skipif(not CUTTING_TASK.is_file(), reason="the shipped cutting task is missing")
@pytest.mark.parametrize("model", ["openai/test-vlm", "ollama_chat/llava"])
def test_a_vlm_answer_drives_a_full_run_and_the_key_stays_out_of_every_file(
    server, tmp_path, monkeypatch, model
):
    from keymps import run_task

    monkeypatch.setenv("OPENAI_API_KEY", CANARY)  # the provider's standard variable
    # one cut across the 15 cm pizza (the 320 px crop's object spans 10-310): the outcome passes
    crop_answer = {"keyword": "straight", "pairs": [[[5, 160], [315, 160]]], "rationale": "x"}
    server.script(Reply.text_answer("```json\n{oops"), Reply.json_answer(crop_answer))
    run = run_task(
        CUTTING_TASK,
        options=RunOptions(rerun="save", record=tmp_path / "cassette.jsonl"),
        overrides=RunOverrides(
            model=model,
            api_base=server.openai_base if model.startswith("openai") else server.url,
            out=tmp_path / "run",
        ),
    )
    assert run.backend == "litellm"
    if model.startswith("openai"):
        assert all(r.headers["authorization"] == f"Bearer {CANARY}" for r in server.chat_requests)
    else:
        assert [r.path for r in server.chat_requests] == ["/api/chat", "/api/chat"]
    record = json.loads((run.folder / "run.json").read_text())
    assert record["keyword"] == "straight" and record["vlm"]["calls"] == 2
    assert record["pairs_crop_px"] == crop_answer["pairs"]
    assert (run.folder / "trajectory.csv").is_file()
    written = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert any(p.suffix == ".rrd" for p in written) and (tmp_path / "cassette.jsonl") in written
    for path in written:
        assert CANARY.encode() not in path.read_bytes(), path


@pytest.mark.skipif(not CUTTING_TASK.is_file(), reason="the shipped cutting task is missing")
def test_an_invalid_plan_stops_the_run_before_anything_moves(server, tmp_path):
    from keymps import run_task
    from keymps.errors import StageError

    outside = {"keyword": "straight", "pairs": [[[40, 150], [5000, 150]]], "rationale": "x"}
    server.script(Reply.json_answer(outside), Reply.json_answer(outside))
    with pytest.raises(StageError, match="^plan: .*outside the image"):
        run_task(
            CUTTING_TASK,
            options=RunOptions(rerun="off", no_cache=True),
            overrides=RunOverrides(
                model="openai/test-vlm", api_base=server.openai_base, out=tmp_path / "run"
            ),
        )
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["ok"] is False and record["keyword"] is None
    assert not (tmp_path / "run" / "trajectory.csv").exists()
    assert "execute" not in record["timings_s"]


A_PROGRAM_THAT_PLANS = """
import sys
import numpy as np
from keymps.default_plugins.litellm.backend import make_backend
from keymps.types import PlanRequest

backend = make_backend({"model": "openai/test-vlm", "api_base": sys.argv[1], "retries": 0})
request = PlanRequest(
    "Cut it in half", np.zeros((8, 8, 3), np.uint8), None, (0.001, 0.001), {"straight": "a cut"},
    0.05, 4, [{"role": "user", "content": "Cut it in half"}], {"name": "plan", "schema": {}},
)
print(backend.complete(request).text)
"""


def test_a_program_that_planned_exits_without_an_unclosed_connection(server):
    """litellm keeps the connection open for the next call and, at exit, closes only its async
    clients: a program calling keymps (not the keymps command, which skips the teardown) was
    told `ResourceWarning: unclosed <socket ...>` as it ended."""
    program = [sys.executable, "-W", "error::ResourceWarning", "-c", A_PROGRAM_THAT_PLANS]
    done = subprocess.run(
        [*program, server.openai_base], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == GOOD and len(server.chat_requests) == 1
    assert "ResourceWarning" not in done.stderr, done.stderr
