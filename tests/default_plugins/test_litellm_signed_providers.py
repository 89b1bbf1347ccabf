"""Providers that sign requests with credentials litellm finds itself get no task-only server.

`sagemaker_chat/` and `sagemaker_nova/` were not on the refusal list: with a server only the
task names, litellm signed the request with the user's AWS credentials. Every provider whose
name starts with bedrock, sagemaker, vertex_ai, oci, snowflake, watsonx or github_copilot is
refused before any request (a real server on 127.0.0.1 hears nothing); the user's own server
is not refused.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest
from helpers.fuzz_support import REPO, RecordingExecutor, assert_clean_error, install, task_copy
from helpers.vlm_server import VlmServer

import keymps
from keymps.errors import KeympsError
from keymps.run import RunOptions, RunOverrides

SIGNED = [
    "bedrock/anthropic.claude-v2",
    "bedrock_converse/x",
    "sagemaker/x",
    "sagemaker_chat/x",
    "sagemaker_nova/x",
    "vertex_ai/gemini-pro",
    "vertex_ai_beta/x",
    "oci/x",
    "snowflake/x",
    "watsonx/x",
    "watsonx_text/x",
    "github_copilot/x",
]


@pytest.fixture(scope="module")
def server() -> Any:
    from keymps.default_plugins.litellm.backend import import_litellm

    import_litellm()  # seconds, once
    with VlmServer(responder=lambda request: json.dumps({"keyword": "line"})) as running:
        yield running


@pytest.fixture(autouse=True)
def _isolated(keymps_plugins: Any, monkeypatch: Any, tmp_path: Path, server: Any) -> None:
    install(keymps_plugins)
    monkeypatch.setenv("KEYMPS_CONFIG", str(tmp_path / "user-config.yaml"))
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "AKIAEXAMPLECANARY01")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "canary-secret-access-key-000")
    server.reset()


@pytest.mark.parametrize("model", SIGNED)
def test_a_task_only_server_is_refused_for_a_provider_that_signs_itself(
    model: str, server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    shutil.copy(REPO / "tasks/scenes/round_cake.png", tmp_path / "scene.png")  # the task's own
    task = task_copy(
        tmp_path,
        **{
            "model: openai/gpt-4o": f"model: {model}\n  api_base: {server.openai_base}",
            "backend: auto": "backend: litellm",
            f"{REPO}/tasks/scenes/round_cake.png": "scene.png",
        },
    )
    with pytest.raises(KeympsError) as caught, pytest.warns(UserWarning):
        keymps.run_task(
            task,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(executor="recording", out=tmp_path / "run"),
        )
    assert_clean_error(caught.value)
    assert "signs every request with your cloud credentials" in str(caught.value)
    assert server.requests == [] and RecordingExecutor.calls == []
    fuzz_counter.add("VLM attacks/trust", ("signed provider, task-only server", model), "refused")
