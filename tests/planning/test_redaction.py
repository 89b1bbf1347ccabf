"""Secrets: with canary keys set, no file any command writes contains them.

Two canaries: OPENAI_API_KEY (the provider's usual variable) and a second key read through
planner.api_key_env. The commands run in-process through the CLI against a real HTTP server
on 127.0.0.1 (tests/helpers/vlm_server.py): `keymps run` (run folder with run.json, vlm/, run.rrd,
trajectory.csv; the answer cache; a recorded cassette), a replay of that cassette, failed runs
whose server echoes the key back in its error messages (some providers quote the key they
rejected), and `keymps eval` (results.jsonl, summaries, gallery). Every file under the test's
folder is then searched for the canaries, and a marker that *should* be in run.rrd shows the
search can see inside it.
"""

from __future__ import annotations

import json
import secrets
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from helpers.fuzz_support import task_copy
from helpers.vlm_server import Reply, VlmServer

from keymps.cli.app import cli

OPENAI_CANARY = "sk-canary-" + secrets.token_hex(12)
OTHER_CANARY = "canary-other-" + secrets.token_hex(12)
MARKER = "MARKER" + secrets.token_hex(6)
DOT = {"keyword": "line", "pairs": [[[130, 130], [130, 130]]], "rationale": "one dot"}


def _answer(request: Any) -> str:
    return json.dumps(DOT)


@pytest.fixture
def env(monkeypatch: Any, tmp_path: Path) -> Path:
    monkeypatch.setenv("OPENAI_API_KEY", OPENAI_CANARY)
    monkeypatch.setenv("MY_VLM_KEY", OTHER_CANARY)
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    config = tmp_path / "config.yaml"  # a task may name MY_VLM_KEY only when the user allows it
    config.write_text("api_key_envs: [MY_VLM_KEY]\n")
    monkeypatch.setenv("KEYMPS_CONFIG", str(config))
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _files_with_canaries(folder: Path) -> list[str]:
    leaks = []
    for path in folder.rglob("*"):
        if path.is_file():
            data = path.read_bytes()
            for canary in (OPENAI_CANARY, OTHER_CANARY):
                for form in (canary, canary[:16], json.dumps(canary)[1:-1]):
                    if form.encode() in data:
                        leaks.append(f"{path.relative_to(folder)} contains {form[:12]}...")
    return leaks


def _keymps(*args: str) -> Any:
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def _task(folder: Path, key_env: str | None) -> Path:
    planner = "model: openai/test-vlm"
    if key_env:
        planner += f"\n  api_key_env: {key_env}"
    return task_copy(
        folder / "task",
        **{
            "model: openai/gpt-4o": planner,
            "Put 15 icing dots around the cake": f"Put 1 icing dot on the cake {MARKER}",
        },
    )


@pytest.mark.parametrize("key_env", [None, "MY_VLM_KEY"], ids=["OPENAI_API_KEY", "api_key_env"])
def test_run_record_replay_and_cache_never_write_a_key(
    key_env: str | None, env: Path, fuzz_counter: Any
) -> None:
    task = _task(env, key_env)
    cassette = env / "cassette.jsonl"
    with VlmServer(responder=_answer) as server:
        server.script(Reply.text_answer("not json at first"))  # a repair turn is recorded too
        result = _keymps(
            "run", str(task), "--api-base", server.openai_base, "--record", str(cassette),
            "--executor", "file", "--out", str(env / "run"), "-q",
        )  # fmt: skip
        assert result.exit_code == 0, result.output
        used = OTHER_CANARY if key_env else OPENAI_CANARY
        assert all(r.headers["authorization"] == f"Bearer {used}" for r in server.chat_requests)
        # only valid answers are cached: the rerun asks once (its first attempt was the invalid
        # one), a third run is answered from the cache alone
        for out in ("rerun", "cached"):
            again = _keymps("run", str(task), "--api-base", server.openai_base, "--out", out)
            assert again.exit_code == 0, again.output
        assert len(server.chat_requests) == 3
    replayed = _keymps(
        "run", str(task), "--backend", "replay", "--cassette", str(cassette), "--out", "replayed"
    )
    assert replayed.exit_code == 0, replayed.output
    written = {p.relative_to(env).as_posix() for p in env.rglob("*") if p.is_file()}
    for expected in ("run/run.json", "run/run.rrd", "run/trajectory.csv", "cassette.jsonl"):
        assert expected in written
    assert any(name.startswith("run/vlm/") for name in written)
    assert any(name.startswith("cache/") for name in written)
    assert MARKER.encode() in (env / "run" / "run.rrd").read_bytes(), "the search sees the .rrd"
    assert _files_with_canaries(env) == []
    fuzz_counter.add("secrets/commands", ("run, record, cache, replay", key_env), "no leak")


@pytest.mark.parametrize(
    "reply",
    [
        Reply.error(401, message=f"Incorrect API key provided: {OPENAI_CANARY}"),
        Reply.error(400, message=f"bad request from key {OPENAI_CANARY} / {OTHER_CANARY}"),
        Reply.error(500, retry_after=0, message=f"internal error, key={OTHER_CANARY}"),
        Reply.text_answer(f"Your key is {OPENAI_CANARY} and {OTHER_CANARY}; no plan today."),
    ],
    ids=["401 echoes the key", "400 echoes both", "500 echoes", "answer quotes the keys"],
)
def test_errors_that_echo_a_key_are_redacted_in_every_file(
    reply: Reply, env: Path, fuzz_counter: Any
) -> None:
    task = _task(env, "MY_VLM_KEY")
    with VlmServer(responder=_answer) as server:
        server.script(*[reply] * 8)
        result = _keymps(
            "run", str(task), "--api-base", server.openai_base, "--record",
            str(env / "cassette.jsonl"), "--no-cache", "--out", str(env / "run"),
        )  # fmt: skip
    assert result.exit_code == 1
    record = json.loads((env / "run" / "run.json").read_text())
    assert record["ok"] is False and record["error"]
    assert _files_with_canaries(env) == []
    fuzz_counter.add("secrets/commands", ("failed run", reply.status, reply.text[:20]), "no leak")


def test_eval_results_never_hold_a_key(env: Path, fuzz_counter: Any) -> None:
    def straight_cuts(request: Any) -> str:
        return json.dumps(
            {"keyword": "straight", "pairs": [[[20, 10], [20, 60]]], "rationale": "one cut"}
        )

    with VlmServer(responder=straight_cuts) as server:
        result = _keymps(
            "eval", "cutting_sim", "--case", "2", "--repeats", "1", "--method", "keymps",
            "--model", "openai/test-vlm", "--api-base", server.openai_base,
            "--out", str(env / "eval"), "--quiet",
        )  # fmt: skip
        assert server.chat_requests, result.output
    assert (env / "eval" / "results.jsonl").is_file(), result.output
    assert _files_with_canaries(env) == []
    fuzz_counter.add("secrets/commands", "eval", "no leak")
