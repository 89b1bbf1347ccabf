"""Answers in every coordinate convention and as named designs, over real HTTP to a local
OpenAI-compatible server (tests/helpers/vlm_server.py): each gives exactly the expected pairs."""

from __future__ import annotations

import base64
import json

import cv2
import numpy as np
import pytest
from helpers.synthetic_crops import CUTTING, ICING, make_scene, plan_for
from helpers.vlm_server import Reply, VlmServer

from keymps.planning.coordinates import from_pixels, resolve, sent_size, to_pixels
from keymps.run import RunOptions, RunOverrides

KEY = "sk-forms-test-0a1b2c3d"
NULLS = {"count": None, "layers": None, "slice_width_cm": None, "object_length_cm": None,
         "orientation": None, "text": None}  # fmt: skip


@pytest.fixture(scope="module")
def server():
    with VlmServer() as running:
        yield running


@pytest.fixture(autouse=True)
def _isolated(server, monkeypatch, tmp_path):
    server.reset()
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("KEYMPS_TEST_VLM_KEY", KEY)


def _plan(server, scene, tmp_path, sentence, primitives=CUTTING, **planner):
    planner.setdefault("api_base", server.openai_base)
    planner.setdefault("api_key_env", "KEYMPS_TEST_VLM_KEY")
    planner.setdefault("cache", False)
    return plan_for(
        sentence, scene, primitives, backend="litellm", folder=tmp_path / "run",
        model=planner.pop("model", "openai/test-vlm"), **planner,
    )  # fmt: skip


def _sent_image(server) -> np.ndarray:
    url = server.chat_requests[-1].body["messages"][1]["content"][1]["image_url"]["url"]
    data = base64.b64decode(url.split(",", 1)[1])
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)


def _system(server) -> str:
    return server.chat_requests[-1].body["messages"][0]["content"]


# --- coordinate conventions --------------------------------------------------------------------


@pytest.mark.parametrize("convention", ["pixels", "xy_1000", "yx_1000"])
def test_answers_in_each_convention_give_the_exact_crop_pixels(server, tmp_path, convention):
    scene = make_scene("ellipse", (220, 90))
    width, height = scene.detection.crop_size_px
    expected = np.array([[[12.5, 30.0], [150.25, 60.5]], [[40.0, 0.0], [40.0, float(height)]]])
    written = from_pixels(expected, convention, (width, height))
    server.script(Reply.json_answer({"keyword": "straight", "pairs": written.tolist(),
                                     "design": None, "rationale": "two cuts"}))  # fmt: skip
    plan, _ = _plan(server, scene, tmp_path, "Cut it into 3 pieces", coordinates=convention)
    assert np.allclose(plan.pairs_crop_px, expected, atol=1e-9)
    assert plan.coordinates == convention
    system = _system(server)
    schema = server.chat_requests[-1].body["response_format"]["json_schema"]["schema"]
    point = schema["properties"]["pairs"]["items"]["items"]["description"]
    if convention == "pixels":
        assert f"{width} x {height} pixels" in system and "0 <= x <=" in system
        assert point.startswith("[x, y] in pixels")
    else:
        order = "[y, x]" if convention == "yx_1000" else "[x, y]"
        assert f"normalized to 0-1000, written {order}" in system
        assert point.startswith(f"{order} normalized to 0-1000")
        # the examples follow the convention: the 400 x 200 example's box corner (20, 40)
        corner = "[200, 50]" if convention == "yx_1000" else "[50, 200]"
        assert f"runs from {corner}" in system


def test_a_point_outside_the_normalized_range_is_sent_back_for_repair(server, tmp_path):
    scene = make_scene("disk", (120, 120))
    server.script(
        Reply.json_answer({"keyword": "straight", "pairs": [[[10, 20], [1200, 20]]],
                           "design": None, "rationale": ""}),
        Reply.json_answer({"keyword": "straight", "pairs": [[[500, 0], [500, 1000]]],
                           "design": None, "rationale": ""}),
    )  # fmt: skip
    plan, _ = _plan(server, scene, tmp_path, "Cut it in half", coordinates="yx_1000")
    repair = json.dumps(server.chat_requests[1].body["messages"][-1])
    assert "[y, x] normalized to 0..1000" in repair
    width, height = scene.detection.crop_size_px
    assert np.allclose(plan.pairs_crop_px, [[[0, height / 2], [width, height / 2]]])


def test_auto_picks_the_convention_by_model_family():
    assert resolve("auto", "gemini/gemini-2.0-flash") == "yx_1000"
    assert resolve("auto", "vertex_ai/gemini-1.5-pro") == "yx_1000"
    assert resolve("auto", "openai/gpt-4o") == "pixels"
    assert resolve("auto", "anthropic/claude-sonnet-4-5") == "pixels"
    assert resolve("auto", None) == "pixels"
    assert resolve("xy_1000", "gemini/gemini-2.0-flash") == "xy_1000"


def test_conventions_round_trip():
    rng = np.random.default_rng(3)
    for _ in range(200):
        size = (int(rng.integers(20, 3000)), int(rng.integers(20, 3000)))
        points = rng.uniform(0, 1, (5, 2, 2)) * size
        for convention in ("pixels", "xy_1000", "yx_1000"):
            back = to_pixels(from_pixels(points, convention, size), convention, size)
            assert np.allclose(back, points, rtol=0, atol=1e-9)


# --- crops larger than the provider accepts -----------------------------------------------------


def test_a_large_crop_is_downscaled_and_the_answer_mapped_back(server, tmp_path):
    scene = make_scene("disk", (700, 700))  # 0.5 mm/px: a 1440 px crop, more than 768
    crop_size = scene.detection.crop_size_px
    sent = sent_size(crop_size, "openai/test-vlm")
    assert max(sent) < max(crop_size) and min(sent) == 768
    # the scripted model answers one cut through the middle of the image it receives
    server.responder = lambda request: json.dumps(_middle_cut(request))
    try:
        plan, _ = _plan(server, scene, tmp_path, "Cut it in half")
    finally:
        server.responder = lambda request: "{}"
    image = _sent_image(server)
    assert (image.shape[1], image.shape[0]) == sent
    assert f"{sent[0]} x {sent[1]} pixels" in _system(server)
    width, height = crop_size
    assert np.allclose(plan.pairs_crop_px, [[[0, height / 2], [width, height / 2]]], atol=1e-9)
    assert plan.image_sent_px == sent


def _middle_cut(request) -> dict:
    url = request.body["messages"][1]["content"][1]["image_url"]["url"]
    image = cv2.imdecode(
        np.frombuffer(base64.b64decode(url.split(",", 1)[1]), np.uint8), cv2.IMREAD_COLOR
    )
    height, width = image.shape[:2]
    pairs = [[[0, height / 2], [width, height / 2]]]
    return {"keyword": "straight", "pairs": pairs, "design": None, "rationale": "halves"}


@pytest.mark.parametrize(
    ("model", "crop", "expected"),
    [
        ("openai/gpt-4o", (3000, 1000), (2048, 682)),
        ("openai/gpt-4o", (1000, 1000), (768, 768)),
        ("openai/gpt-4o", (500, 300), (500, 300)),
        ("anthropic/claude-sonnet-4-5", (3000, 1000), (1568, 522)),
        ("anthropic/claude-sonnet-4-5", (1000, 1000), (1000, 1000)),
        ("ollama/llava", (5000, 5000), (5000, 5000)),
    ],
)
def test_provider_image_limits(model, crop, expected):
    assert sent_size(crop, model) == expected


# --- named designs -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("shape", "size", "design", "sentence", "primitives", "keyword"),
    [
        ("disk", (200, 200), {"name": "equal", "count": 6}, "cut it into 6 equal parts",
         CUTTING, "straight"),
        ("rect", (180, 180), {"name": "equal", "count": 6}, "cut it into 6 equal parts",
         CUTTING, "straight"),
        ("ellipse", (300, 80), {"name": "width", "slice_width_cm": 4, "orientation": "vertical"},
         "cut it vertically into 4 cm slices", CUTTING, "straight"),
        ("disk", (220, 220), {"name": "dots_ring", "count": 9}, "put 9 dots around the cake",
         ICING, "line"),
        ("disk", (220, 220), {"name": "dots_ring", "layers": 3}, "put 3 rings of dots", ICING,
         "line"),
        ("rect", (200, 200), {"name": "digits", "text": "27"}, "write 27 on the cake", ICING,
         "line"),
    ],
)  # fmt: skip
def test_a_named_design_is_laid_out_exactly_like_the_offline_planner(
    server, tmp_path, shape, size, design, sentence, primitives, keyword
):
    scene = make_scene(shape, size)
    offline, _ = plan_for(sentence, scene, primitives)
    server.script(Reply.json_answer({"keyword": keyword, "pairs": None,
                                     "design": {**NULLS, **design}, "rationale": "named"}))  # fmt: skip
    plan, _ = _plan(server, scene, tmp_path, "Do as the picture suggests", primitives)
    # the offline planner's JSON answer rounds to 0.001 px; the design itself is the same
    assert np.allclose(plan.pairs_crop_px, offline.pairs_crop_px, atol=5e-4)
    assert plan.design is not None and plan.design["name"] == design["name"]
    assert "named design laid out by keymps" in plan.rationale
    system = _system(server)
    assert f"- {design['name']}" in system  # the prompt lists the designs


def test_invalid_designs_are_sent_back_with_what_is_wrong(server, tmp_path):
    scene = make_scene("disk", (200, 200))
    server.script(
        Reply.json_answer({"keyword": "straight", "pairs": None,
                           "design": {**NULLS, "name": "heart"}, "rationale": ""}),
        Reply.json_answer({"keyword": "straight", "pairs": None,
                           "design": {**NULLS, "name": "equal"}, "rationale": ""}),
        Reply.json_answer({"keyword": "straight", "pairs": [[[1, 1], [9, 9]]],
                           "design": {**NULLS, "name": "equal", "count": 4}, "rationale": ""}),
        Reply.json_answer({"keyword": "straight", "pairs": None,
                           "design": {**NULLS, "name": "equal", "count": 4}, "rationale": ""}),
    )  # fmt: skip
    plan, _ = _plan(server, scene, tmp_path, "Cut it into 4", attempts=4)
    repairs = [json.dumps(r.body["messages"][-1]) for r in server.chat_requests[1:]]
    assert "design.name 'heart' is not one of" in repairs[0]
    assert "design equal needs count" in repairs[1]
    assert "not both" in repairs[2]
    assert plan.num_pairs == 2


@pytest.mark.parametrize("mode", ["pairs", "design"])
def test_planner_answer_limits_the_answer_form(server, tmp_path, mode):
    scene = make_scene("disk", (200, 200))
    design = {"keyword": "straight", "design": {**NULLS, "name": "equal", "count": 4}}
    pairs = {"keyword": "straight", "pairs": [[[10, 100], [190, 100]]]}
    wrong, right = (design, pairs) if mode == "pairs" else (pairs, design)
    server.script(Reply.json_answer(wrong), Reply.json_answer(right))
    plan, _ = _plan(server, scene, tmp_path, "Cut it into 4", answer=mode)
    schema = server.chat_requests[0].body["response_format"]["json_schema"]["schema"]
    form = {"pairs", "intent"} if mode == "pairs" else {"design"}  # a design states its intent
    assert set(schema["properties"]) == {"keyword", *form, "rationale"}
    assert len(server.chat_requests) == 2
    assert (plan.design is None) == (mode == "pairs")
    if mode == "pairs":
        assert "Not used for this task" in _system(server)


def test_a_design_of_the_other_family_is_refused(server, tmp_path):
    from keymps.errors import KeympsError

    scene = make_scene("disk", (200, 200))
    server.script(Reply.json_answer({"keyword": "straight", "pairs": None,
                                     "design": {**NULLS, "name": "dots_ring", "count": 9},
                                     "rationale": ""}))  # fmt: skip
    with pytest.raises(KeympsError, match="icing design 'dots_ring' with the cutting primitive"):
        _plan(server, scene, tmp_path, "Make it nice")


# --- what is sent and counted -------------------------------------------------------------------


def test_html_comments_of_the_template_are_not_sent(server, tmp_path):
    scene = make_scene("disk", (150, 150))
    server.script(Reply.json_answer({"keyword": "straight", "pairs": [[[0, 10], [50, 10]]]}))
    _plan(server, scene, tmp_path, "Cut it in half")
    system = _system(server)
    assert "<!--" not in system and "copy this file" not in system
    assert system.startswith("# Task: robot food cutting")


def test_the_offline_planner_is_not_counted_as_a_vlm_call(tmp_path):
    from pathlib import Path

    import keymps

    repo = Path(__file__).resolve().parents[2]
    run = keymps.run_task(repo / "tasks" / "object_cutting.yaml", options=RunOptions(rerun="off", quiet=True), overrides=RunOverrides(backend="offline", executor="file", out=tmp_path / "run"))  # fmt: skip
    record = json.loads((run.folder / "run.json").read_text())
    assert record["vlm"]["calls"] == 0 and record["backend"] == "offline"
    assert record["answer"] == {"coordinates": "pixels", "design": None, "image_sent_px": None}
    assert len(run.stages.plan.calls) == 1  # still recorded under vlm/


def test_a_comment_may_hold_any_braces_and_errors_keep_their_line():
    from keymps.errors import KeympsError
    from keymps.planning.prompt import render_template

    template = "<!-- notes: {{not_a_placeholder}}\nline 2 -->\nHello {{instruction}}\n{{nope}}\n"
    with pytest.raises(KeympsError, match=r"^t.md:4: unknown placeholder \{\{nope\}\}"):
        render_template(template, {"instruction": "x"}, "t.md")
    assert render_template(template[:-9], {"instruction": "x"}, "t.md") == "Hello x"
