"""Recording answers to a cassette and replaying them without a VLM."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers.synthetic_crops import ICING, make_scene, plan_for
from helpers.vlm_server import Reply, VlmServer

from keymps.errors import KeympsError
from keymps.run import RunOptions

CANARY = "sk-canary-replay-5a6b7c8d"
ANSWER = {
    "keyword": "line",
    "pairs": [[[60, 60], [60, 60]], [[90, 60], [150, 60]]],
    "rationale": "a dot and a line",
}
SENTENCE = "Put a dot and a line on the cake"


@pytest.fixture(scope="module")
def scene():
    return make_scene("disk", (160, 160))


@pytest.fixture
def recorded(scene, tmp_path, monkeypatch):
    """A cassette recorded from the local server: a malformed answer, then its repair."""
    monkeypatch.setenv("KEYMPS_REPLAY_KEY", CANARY)
    cassette = tmp_path / "answers.jsonl"
    with VlmServer(responder=lambda request: json.dumps(ANSWER)) as server:
        server.script(Reply.text_answer("{broken"))
        plan, _ = plan_for(
            SENTENCE,
            scene,
            ICING,
            backend="litellm",
            folder=tmp_path / "recording",
            options=RunOptions(record=cassette, no_cache=True),
            model="openai/test-vlm",
            api_base=server.openai_base,
            api_key_env="KEYMPS_REPLAY_KEY",
        )
        assert len(server.chat_requests) == 2
    return cassette, plan


def test_cassette_lines_hold_digests_and_answers_but_no_key(recorded):
    cassette, _ = recorded
    lines = [json.loads(line) for line in cassette.read_text().splitlines()]
    assert [line["attempt"] for line in lines] == [1, 2]
    assert lines[0]["answer"] == "{broken" and json.loads(lines[1]["answer"]) == ANSWER
    assert all(len(line["digest"]) == 64 for line in lines)
    assert CANARY not in cassette.read_text() and "data:image" not in cassette.read_text()


def test_replay_gives_the_same_plan_without_a_vlm(recorded, scene, tmp_path):
    cassette, original = recorded
    replayed, run = plan_for(
        SENTENCE,
        scene,
        ICING,
        backend="replay",
        cassette=cassette,
        folder=tmp_path / "replay",
        model="openai/test-vlm",
    )
    assert replayed.keyword == original.keyword
    assert np.array_equal(replayed.pairs_px, original.pairs_px)
    assert [c.error is None for c in replayed.calls] == [False, True]  # the repair replays too
    assert len(list((run.folder / "vlm").glob("*attempt*.json"))) == 2


def test_an_unseen_request_fails_clearly(recorded, scene, tmp_path):
    cassette, _ = recorded
    with pytest.raises(KeympsError, match="has no answer for this request .*record again"):
        plan_for(
            "Put two dots on the cake",
            scene,
            ICING,
            backend="replay",
            cassette=cassette,
            folder=tmp_path / "unseen",
        )


def test_replay_needs_a_cassette(scene, tmp_path):
    with pytest.raises(KeympsError, match="needs a cassette"):
        plan_for(SENTENCE, scene, ICING, backend="replay", folder=tmp_path / "none")
    with pytest.raises(KeympsError, match="cassette not found"):
        plan_for(
            SENTENCE,
            scene,
            ICING,
            backend="replay",
            cassette=tmp_path / "missing.jsonl",
            folder=tmp_path / "missing",
        )


def test_a_damaged_cassette_names_the_line(scene, tmp_path):
    cassette = tmp_path / "bad.jsonl"
    cassette.write_text('{"digest": "a", "answer": "{}"}\nnot json\n')
    with pytest.raises(KeympsError, match=r"bad\.jsonl:2: not a JSON line"):
        plan_for(
            SENTENCE, scene, ICING, backend="replay", cassette=cassette, folder=tmp_path / "bad"
        )


def test_offline_plans_can_be_recorded_and_replayed(scene, tmp_path):
    cassette = tmp_path / "offline.jsonl"
    offline, _ = plan_for(
        "Put 12 icing dots around the cake",
        scene,
        ICING,
        folder=tmp_path / "a",
        options=RunOptions(record=cassette),
    )
    replayed, _ = plan_for(
        "Put 12 icing dots around the cake",
        scene,
        ICING,
        backend="replay",
        cassette=cassette,
        folder=tmp_path / "b",
    )
    assert np.array_equal(offline.pairs_px, replayed.pairs_px)
