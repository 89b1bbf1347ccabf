"""Planning core: backend choice, answer validation, prompt templates, the answer cache."""

from __future__ import annotations

import json
from typing import get_args

import numpy as np
import pytest
from helpers.synthetic_crops import CUTTING, ICING, make_scene, make_task, plan_for
from helpers.vlm_server import Reply, VlmServer

from keymps.errors import KeympsError
from keymps.planning.answer import answer_schema, extract_json, parse_and_validate
from keymps.planning.planner import choose_backend
from keymps.planning.prompt import (
    PLACEHOLDERS,
    find_prompt,
    output_format,
    prompt_family,
    render_template,
)
from keymps.planning.session import redact
from keymps.plugin.hookspecs import hookimpl
from keymps.run import RunOptions
from keymps.types import PieceShape

GOOD = {"keyword": "sawing", "pairs": [[[10, 20], [150, 20]]], "rationale": "one cut"}


@pytest.fixture(scope="module")
def scene():
    return make_scene("ellipse", (200, 80))


# --- choose_backend --------------------------------------------------------------------------


@pytest.fixture
def no_keys(monkeypatch):
    for name in (
        "OPENAI_API_KEY",
        "ANTHROPIC_API_KEY",
        "GEMINI_API_KEY",
        "GOOGLE_API_KEY",
        "OLLAMA_API_BASE",
        "MY_VLM_KEY",
    ):
        monkeypatch.delenv(name, raising=False)
    return monkeypatch


def test_auto_without_a_model_is_offline(scene, no_keys):
    task = make_task("Cut it in half", scene, CUTTING)
    backend, reason = choose_backend(task, None, None, None)
    assert backend == "offline" and "no VLM model" in reason


def test_auto_with_a_model_but_no_key_is_offline_and_names_the_variable(scene, no_keys):
    task = make_task("Cut it in half", scene, CUTTING, model="openai/gpt-4o")
    backend, reason = choose_backend(task, None, None, None)
    assert backend == "offline" and "$OPENAI_API_KEY" in reason


@pytest.mark.parametrize(
    ("model", "variable"),
    [
        ("openai/gpt-4o", "OPENAI_API_KEY"),
        ("anthropic/claude-sonnet-4-5", "ANTHROPIC_API_KEY"),
        ("claude-3-5-sonnet-latest", "ANTHROPIC_API_KEY"),
        ("gemini/gemini-2.0-flash", "GEMINI_API_KEY"),
    ],
)
def test_auto_with_the_providers_key_is_litellm(scene, no_keys, model, variable):
    no_keys.setenv(variable, "sk-test-value")
    task = make_task("Cut it in half", scene, CUTTING, model=model)
    backend, reason = choose_backend(task, None, None, None)
    assert backend == "litellm" and f"${variable}" in reason and "sk-test" not in reason


def test_auto_with_task_key_variable_or_api_base_is_litellm(scene, no_keys):
    task = make_task("Cut it in half", scene, CUTTING, model="openai/x", api_key_env="MY_VLM_KEY")
    assert choose_backend(task, None, None, None)[0] == "offline"
    no_keys.setenv("MY_VLM_KEY", "secret-value-123")
    assert choose_backend(task, None, None, None) == (
        "litellm",
        "model openai/x with credentials from $MY_VLM_KEY",
    )
    plain = make_task("Cut it in half", scene, CUTTING)
    backend, reason = choose_backend(plain, None, "ollama/llava", "http://127.0.0.1:11434")
    assert backend == "litellm" and "http://127.0.0.1:11434" in reason


def test_explicit_backend_wins(scene, no_keys):
    task = make_task("Cut it in half", scene, CUTTING, backend="replay", cassette="a.jsonl")
    assert choose_backend(task, None, None, None)[0] == "replay"
    assert choose_backend(task, "offline", None, None) == (
        "offline",
        "--backend asks for the offline planner",
    )


# --- answers ---------------------------------------------------------------------------------


def test_json_is_found_in_fences_and_prose():
    assert extract_json('```json\n{"a": 1}\n```') == {"a": 1}
    assert extract_json('Sure. {"a": {"b": "}"}} Hope it helps {') == {"a": {"b": "}"}}
    with pytest.raises(ValueError):
        extract_json("no object here")
    assert extract_json('```json\n{"a": 1}\n``` Again: ```{"a": 1}```') == {"a": 1}


@pytest.mark.parametrize(
    "text",
    ['{"a": 1} or {"a": 2}', '```json\n{"a": 1}\n```\n```json\n{"b": 2}\n```', '{"a":1}{"a":[2]}'],
)
def test_an_answer_with_two_different_objects_is_refused(text: str) -> None:
    with pytest.raises(ValueError, match="2 different JSON objects"):
        extract_json(text)


def test_validation_rules():
    keys = ["straight", "sawing"]
    ok, problems = parse_and_validate(json.dumps(GOOD), "combined", keys, (200, 100), 64)
    assert ok is not None and problems == []
    bad = {"keyword": "chop", "pairs": [[[10, 20], [250, 20]], [[-1, 5], [5, 5]]]}
    _, problems = parse_and_validate(json.dumps(bad), "combined", keys, (200, 100), 64)
    assert problems[0] == "keyword 'chop' is not one of: straight, sawing"
    assert any("pair 1 end (250, 20) is outside the image" in p for p in problems)
    assert any("pair 2 start (-1, 5)" in p for p in problems)
    too_many = {**GOOD, "pairs": GOOD["pairs"] * 3}
    _, problems = parse_and_validate(json.dumps(too_many), "combined", keys, (200, 100), 2)
    assert problems == ["pairs: 3 pairs given; give between 1 and 2"]
    _, problems = parse_and_validate(
        '{"keyword": "sawing", "pairs": [[[1, NaN], [2, 2]]]}', "combined", keys, (200, 100), 64
    )
    assert problems and "finite" in problems[0]
    _, problems = parse_and_validate(
        '{"keyword": "sawing", "pairs": [[1, 2]]}', "combined", keys, (200, 100), 64
    )
    assert problems and problems[0].startswith("pairs.0")


def test_cuts_need_two_points_apart_and_no_pair_is_given_twice():
    """A VLM's zero-length cut has no blade direction; a repeated pair cuts (or pipes) twice."""

    def problems(pairs, family="cutting", convention="pixels", keyword="sawing"):
        text = json.dumps({"keyword": keyword, "pairs": pairs})
        keys = ["sawing", "line"]
        return parse_and_validate(
            text, "combined", keys, (200, 100), 64, "pairs", convention, family
        )[1]

    assert problems([[[150, 50], [150, 50]]]) == [
        "pair 1 is a cut 0 long from [150.0, 50.0] to [150.0, 50.0]: a cut needs its start "
        "and end apart (at least 2)"
    ]
    assert problems([[[150, 50], [151, 50.5]]])[0].startswith("pair 1 is a cut 1.11803 long")
    assert problems([[[10, 10], [90, 90]], [[90, 90], [10, 10]], [[10, 10], [90, 90]]]) == [
        "pair 2 repeats pair 1: give each once",
        "pair 3 repeats pair 1: give each once",
    ]
    assert problems([[[500, 500], [500, 505]]], convention="xy_1000")[0].startswith(
        "pair 1 is a cut 5 long"
    )
    # icing: a dot is a pair whose ends meet; the same dot twice, or a line both ways, is not
    assert problems([[[150, 50], [150, 50]], [[20, 20], [20, 20]]], "icing", keyword="line") == []
    assert problems([[[150, 50], [150, 50]], [[150, 50], [150, 50]]], "icing", keyword="line") == [
        "pair 2 repeats pair 1: give each once"
    ]
    assert problems([[[10, 10], [90, 90]], [[90, 90], [10, 10]]], "icing", keyword="line") == []
    assert problems([[[10, 10], [90, 90]], [[12, 10], [92, 90]]]) == []


def test_schema_lists_the_primitives_and_is_strict():
    schema = answer_schema("combined", ["line"], 64)
    body = schema["schema"]
    assert body["properties"]["keyword"]["enum"] == ["line"]
    assert body["required"] == ["keyword", "pairs", "intent", "rationale"]
    assert body["additionalProperties"] is False and schema["strict"] is True
    intent = body["properties"]["intent"]["anyOf"][0]  # strict: every field, each nullable
    assert intent["required"] == list(intent["properties"]) and not intent["additionalProperties"]


def test_the_schema_and_the_prompt_ask_for_every_intent_field_the_outcome_stage_checks():
    """docs/outcome.md's table: a VLM not asked for the pieces' shape or the edge distance
    claims neither, and "3 strips" cut as wedges would pass unchecked."""
    checked = ["pieces", "equal", "orientation", "slice_width_cm", "dots", "rings", "digits",
               "piece_shape", "edge_distance_cm"]  # fmt: skip
    body = answer_schema("combined", ["straight"], 64)["schema"]
    intent = body["properties"]["intent"]["anyOf"][0]
    assert list(intent["properties"]) == checked
    assert intent["properties"]["piece_shape"]["enum"] == [*get_args(PieceShape), None]
    asked = output_format("combined", "pairs", "pixels")
    assert all(f'"{name}": ...' in asked for name in checked)


# --- prompts ---------------------------------------------------------------------------------


def test_shipped_prompts_use_only_known_placeholders(tmp_path):
    for family in ("cutting", "icing"):
        path = find_prompt(None, tmp_path, family)
        text = render_template(path.read_text(), {k: f"<{k}>" for k in PLACEHOLDERS}, str(path))
        assert "{{" not in text and "<output_format>" in text and "<primitives>" in text


def test_unknown_placeholder_names_file_and_line():
    with pytest.raises(KeympsError, match=r"my\.md:2: unknown placeholder \{\{colour\}\}"):
        render_template("ok {{instruction}}\nbad {{colour}}", {}, "my.md")


def test_prompt_family_follows_the_primitives():
    assert prompt_family(ICING) == "icing" and prompt_family(CUTTING) == "cutting"


def test_the_prompt_sent_describes_primitives_and_coordinates(scene, tmp_path):
    plan, run = plan_for("Cut it in half", scene, CUTTING, folder=tmp_path)
    system = plan.calls[0].request["messages"][0]["content"]
    assert "- sawing: Forward and backward sawing" in system
    width, height = scene.detection.crop_size_px
    assert f"{width} x {height} pixels" in system and "top-left" in system
    assert "{{" not in system


def test_redact_removes_keys_and_secret_values():
    data = {"api_key": "abc", "headers": {"Authorization": "Bearer x"}, "text": "key sk-12345678"}
    assert redact(data, ["sk-12345678"]) == {
        "api_key": "[redacted]",
        "headers": {"Authorization": "[redacted]"},
        "text": "key [redacted]",
    }


def test_max_pairs_too_small_for_the_design_is_a_clean_error(scene):
    with pytest.raises(KeympsError, match="more than planner.max_pairs = 2"):
        plan_for("Cut it into 8 equal slices", scene, CUTTING, max_pairs=2)


# --- cache -----------------------------------------------------------------------------------


def test_a_rerun_with_the_same_inputs_costs_no_call(scene, tmp_path, monkeypatch):
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    with VlmServer(responder=lambda request: json.dumps(GOOD)) as server:
        settings = {"model": "openai/test-vlm", "api_base": server.openai_base}
        first, _ = plan_for(
            "Cut it in half", scene, CUTTING, backend="litellm", folder=tmp_path / "a", **settings
        )
        second, _ = plan_for(
            "Cut it in half", scene, CUTTING, backend="litellm", folder=tmp_path / "b", **settings
        )
        assert len(server.chat_requests) == 1
        assert [c.cached for c in second.calls] == [True] and second.calls[0].cost_usd == 0.0
        assert np.array_equal(first.pairs_px, second.pairs_px)
        # another sentence, --no-cache, or planner.cache: false each make a new call
        plan_for(
            "Cut it in two", scene, CUTTING, backend="litellm", folder=tmp_path / "c", **settings
        )
        plan_for(
            "Cut it in half",
            scene,
            CUTTING,
            backend="litellm",
            folder=tmp_path / "d",
            options=RunOptions(no_cache=True),
            **settings,
        )
        plan_for(
            "Cut it in half",
            scene,
            CUTTING,
            backend="litellm",
            folder=tmp_path / "e",
            cache=False,
            **settings,
        )
        assert len(server.chat_requests) == 4
    assert list((tmp_path / "cache").rglob("*.json"))


def test_invalid_answers_are_not_cached(scene, tmp_path, monkeypatch):
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    with VlmServer(responder=lambda request: json.dumps(GOOD)) as server:
        server.script(Reply.text_answer("nonsense"))
        settings = {"model": "openai/test-vlm", "api_base": server.openai_base}
        plan_for(
            "Cut it in half", scene, CUTTING, backend="litellm", folder=tmp_path / "a", **settings
        )
        again, _ = plan_for(
            "Cut it in half", scene, CUTTING, backend="litellm", folder=tmp_path / "b", **settings
        )
        # the invalid first answer was not kept: the rerun asks again (and gets a good answer)
        assert len(server.chat_requests) == 3
        assert [(c.cached, c.error) for c in again.calls] == [(False, None)]


# --- a third-party backend, written against the documented protocol --------------------------


class _TeachingBackend:
    """Answers badly once, then fixes exactly what it was told (a plugin author's backend)."""

    name = "teaching"
    cacheable = False

    def __init__(self, options):
        self.options = options
        self.requests = []

    def complete(self, request):
        from keymps.types import BackendAnswer

        self.requests.append(request)
        if not request.previous_errors:
            return BackendAnswer(text='{"keyword": "chop", "pairs": [[[1, 1], [2, 2]]]}')
        width, height = request.crop_size_px
        answer = {
            "keyword": next(iter(request.primitives)),
            "pairs": [[[0, height / 2], [width, height / 2]]],
            "rationale": "fixed",
        }
        return BackendAnswer(text=json.dumps(answer), prompt_tokens=10, cost_usd=0.001)


def test_a_plugin_backend_gets_the_documented_request(scene, tmp_path, keymps_plugins):
    created: list[_TeachingBackend] = []

    def factory(options):
        created.append(_TeachingBackend(options))
        return created[-1]

    class Plugin:
        @hookimpl
        def register_vlm_backends(self, register):
            register("teaching", factory)

    keymps_plugins.register(Plugin(), name="teaching-plugin")
    plan, _ = plan_for(
        "Cut it in half",
        scene,
        CUTTING,
        backend="teaching",
        folder=tmp_path,
        model="my/model",
        temperature=0.3,
    )
    (backend,) = created
    assert backend.options["model"] == "my/model" and backend.options["temperature"] == 0.3
    first, second = backend.requests
    assert first.crop.shape == scene.detection.crop.shape and first.step == "combined"
    assert first.primitives == CUTTING and first.max_pairs == 64 and first.attempt == 1
    assert first.metres_per_px == pytest.approx((0.0005, 0.0005))
    assert first.schema["schema"]["properties"]["keyword"]["enum"] == list(CUTTING)
    assert second.previous_errors == ("keyword 'chop' is not one of: straight, sawing",)
    assert second.attempt == 2 and second.messages[-2]["role"] == "assistant"
    assert plan.keyword == "straight" and plan.calls[-1].cost_usd == 0.001


def test_keyword_spelling_is_forgiven_only_when_unambiguous():
    keys = ["straight", "sawing"]
    for spelled in ("Sawing", " [sawing] ", '"SAWING"'):
        answer, problems = parse_and_validate(
            json.dumps({**GOOD, "keyword": spelled}), "combined", keys, (200, 100), 64
        )
        assert problems == [] and answer.keyword == "sawing"


def test_impossible_backend_requests_fail_before_any_stage(scene, no_keys):
    task = make_task("Cut it in half", scene, CUTTING)
    with pytest.raises(KeympsError, match=r"unknown planner backend 'gpt' \(available: auto, "):
        choose_backend(task, "gpt", None, None)
    with pytest.raises(KeympsError, match="litellm backend needs a model"):
        choose_backend(task, "litellm", None, None)
    with pytest.raises(KeympsError, match="replay backend needs a cassette"):
        choose_backend(task, "replay", None, None)


def test_offline_planner_answers_in_two_calls_too(scene, tmp_path):
    combined, _ = plan_for("Cut it into 4 equal slices", scene, CUTTING, folder=tmp_path / "a")
    split, run = plan_for(
        "Cut it into 4 equal slices", scene, CUTTING, folder=tmp_path / "b", combined=False
    )
    assert [c.request["step"] for c in split.calls] == ["keyword", "pairs"]
    assert split.keyword == combined.keyword
    assert np.array_equal(split.pairs_px, combined.pairs_px)
    assert sorted(p.name for p in (run.folder / "vlm").glob("*.json")) == [
        "01-keyword-attempt1.json",
        "02-pairs-attempt1.json",
    ]


def test_detector_mask_of_the_whole_image_is_cut_to_the_crop(scene, tmp_path):
    from dataclasses import replace

    from keymps.planning.planner import crop_mask

    full = np.zeros(scene.scene.image.shape[:2], bool)
    x0, y0 = scene.detection.crop_origin_px
    full[y0 + 5, x0 + 7] = True
    detection = replace(scene.detection, mask=full)
    cut = crop_mask(detection, scene.scene)
    assert cut.shape == scene.detection.crop.shape[:2] and cut[5, 7] and cut.sum() == 1


def test_local_servers_are_recognised():
    from keymps.default_plugins.litellm.backend import is_local

    assert is_local("http://127.0.0.1:8000/v1", "openai")
    assert is_local("http://localhost:11434", "ollama")
    assert is_local(None, "ollama")
    assert not is_local(None, "openai") and not is_local("https://api.example.com", "openai")


def test_a_model_named_on_the_command_line_never_falls_back_silently(scene, no_keys):
    task = make_task("Cut it in half", scene, CUTTING)
    with pytest.raises(
        KeympsError, match=r"--model openai/gpt-4o: no credentials \(\$OPENAI_API_KEY"
    ):
        choose_backend(task, None, "openai/gpt-4o", None)
    with pytest.raises(KeympsError) as caught:  # a provider keymps has no key variable for
        choose_backend(task, None, "notaprovider/xyz", None)
    assert str(caught.value).startswith(
        "--model notaprovider/xyz: no credentials (no key variable known for provider "
        "'notaprovider', no api_base); set the key's environment variable"
    )
    assert choose_backend(task, None, "ollama/llava", None)[0] == "litellm"
    in_file = make_task("Cut it in half", scene, CUTTING, model="ollama/llava")
    assert choose_backend(in_file, None, None, None)[0] == "offline"  # needs $OLLAMA_API_BASE
