"""A request carrying a key never follows a redirect to another server (docs/security.md).

The user's own server (`--api-base`) answers every request with a redirect (301, 302, 303, 307,
308) to another origin: another port, `localhost` for `127.0.0.1`, https for http. httpx drops
only `Authorization` on its way there, so Anthropic's `x-api-key` and Gemini's
`x-goog-api-key` went along, and the body (image, prompt) always did. Two real servers on
127.0.0.1: the second must never hear a request, the run must stop once with one line naming
both addresses, and nothing executes. A redirect on the same server is still followed, and
httpx outside keymps' calls still follows every redirect.
"""

from __future__ import annotations

import asyncio
import json
import secrets
from pathlib import Path
from typing import Any

import pytest
from helpers.fuzz_support import (
    RecordingExecutor,
    assert_clean_error,
    install,
    plan_request,
    task_copy,
)
from helpers.vlm_server import Reply, VlmServer

import keymps
from keymps.errors import KeympsError
from keymps.run import RunOptions, RunOverrides

DOT = {"keyword": "line", "pairs": [[[130, 130], [130, 130]]], "rationale": "one dot"}
KEY = "sk-canary-" + secrets.token_hex(12)
PROVIDERS = {
    "openai": ("openai/test-vlm", "OPENAI_API_KEY", "/v1"),
    "anthropic": ("anthropic/claude-3-5-sonnet-20241022", "ANTHROPIC_API_KEY", ""),
    "gemini": ("gemini/gemini-2.0-flash", "GEMINI_API_KEY", ""),
}
"""provider -> (model, its key variable, the path of its base URL)."""


@pytest.fixture(scope="module")
def servers() -> Any:
    """The user's server and another one it redirects to."""
    from keymps.default_plugins.litellm.backend import import_litellm

    import_litellm()  # seconds, once
    with VlmServer(lambda r: json.dumps(DOT)) as own, VlmServer(lambda r: json.dumps(DOT)) as other:
        yield own, other


@pytest.fixture(autouse=True)
def _isolated(keymps_plugins: Any, monkeypatch: Any, tmp_path: Path, servers: Any) -> None:
    install(keymps_plugins)
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("KEYMPS_CONFIG", str(tmp_path / "user-config.yaml"))
    for _model, variable, _path in PROVIDERS.values():
        monkeypatch.setenv(variable, KEY)
    for server in servers:
        server.reset()


def elsewhere(target: str, own: VlmServer, other: VlmServer) -> str:
    return {
        "another port": other.url,
        "localhost": f"http://localhost:{own.port}",
        "https": f"https://127.0.0.1:{own.port}",
    }[target]


def icing_task(folder: Path, model: str) -> Path:
    return task_copy(
        folder,
        **{"model: openai/gpt-4o": f"model: {model}\n  cache: false", "15 icing dots": "1 dot"},
    )


@pytest.mark.parametrize("target", ["another port", "localhost", "https"])
@pytest.mark.parametrize("status", [301, 302, 303, 307, 308])
@pytest.mark.parametrize("provider", sorted(PROVIDERS))
def test_a_redirect_to_another_server_is_not_followed(
    provider: str, status: int, target: str, servers: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    own, other = servers
    model, _variable, path = PROVIDERS[provider]
    to = elsewhere(target, own, other) + "/v1/chat/completions"
    own.script(Reply.redirect(status, to))
    with pytest.raises(KeympsError) as caught:
        keymps.run_task(
            icing_task(tmp_path / "task", model),
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(
                api_base=own.url + path, executor="recording", out=tmp_path / "run"
            ),
        )
    assert_clean_error(caught.value)
    message = str(caught.value)
    assert f"redirected the request (HTTP {status})" in message, message
    assert "another server: not followed" in message and KEY not in message
    assert len(own.requests) == 1, "not retried"
    assert KEY in json.dumps(own.requests[0].headers), "the user's own server got the key"
    assert other.requests == [] and RecordingExecutor.calls == []
    if target != "another port":  # the same port: only the redirecting request arrived
        assert [r.path for r in own.requests] == [own.requests[0].path]
    fuzz_counter.add("VLM attacks/redirects", (provider, status, target), "not followed")


def test_a_redirect_on_the_same_server_is_still_followed(servers: Any, tmp_path: Path) -> None:
    own, _other = servers
    own.script(Reply.redirect(307, f"{own.url}/v2/chat/completions"))
    keymps.run_task(
        icing_task(tmp_path / "task", "openai/test-vlm"),
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(
            api_base=own.openai_base, executor="recording", out=tmp_path / "run"
        ),
    )
    assert [r.path for r in own.chat_requests] == ["/v1/chat/completions", "/v2/chat/completions"]
    assert len(RecordingExecutor.calls) == 1


def test_the_async_call_of_keymps_eval_is_not_redirected_either(servers: Any) -> None:
    from keymps.default_plugins.litellm.backend import LitellmBackend, LitellmOptions

    own, other = servers
    backend = LitellmBackend(
        LitellmOptions(
            model="anthropic/claude-3-5-sonnet-20241022",
            api_base=own.url,
            api_base_trusted=True,
            timeout_s=30,
        )
    )
    request = plan_request(30, {"name": "plan", "strict": True, "schema": {"type": "object"}})
    own.script(Reply.redirect(307, f"{other.url}/v1/messages"))
    with pytest.raises(KeympsError, match="another server: not followed"):
        asyncio.run(backend.acomplete(request))
    assert len(own.requests) == 1 and other.requests == []


def test_outside_keymps_calls_httpx_follows_redirects_as_its_own(servers: Any) -> None:
    import httpx

    from keymps.default_plugins.litellm.request_guard import install as install_guard

    install_guard()
    own, other = servers
    own.script(Reply.redirect(307, f"{other.url}/v1/chat/completions"))
    with httpx.Client(follow_redirects=True) as client:
        answer = client.post(f"{own.openai_base}/chat/completions", json={"model": "m"})
    assert answer.status_code == 200 and len(other.requests) == 1
