"""Faults on the VLM path, injected by a real HTTP server on 127.0.0.1 (tests/helpers/vlm_server.py).

Connection refused, a reset mid-answer, answers slower than planner.timeout_s, 429 with
Retry-After, 500s, cut-off and broken JSON, bytes that are not HTTP: every full run ends either
in a retry that succeeds or in one clean error line, within a time the configuration bounds; the
run folder's vlm/ records what happened, and the recording executor (standing in for the robot)
is never called after an error. test_litellm_backend.py covers the backend alone; here the
faults go through `keymps.run_task`, alone and in random sequences (hypothesis).
"""

from __future__ import annotations

import json
import os
import socket
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest
from helpers.fuzz_support import RecordingExecutor, assert_clean_error, install, task_copy
from helpers.vlm_server import Reply, VlmServer
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import keymps
from keymps.errors import KeympsError
from keymps.plugin.hookspecs import hookimpl
from keymps.run import RunOptions, RunOverrides

DOT = {"keyword": "line", "pairs": [[[130, 130], [130, 130]]], "rationale": "one dot"}
TIMEOUT_S = 0.6
BACKOFF_S = 0.05
RETRIES = 3  # the litellm backend's default


class QuickRetries:
    """The real litellm backend, registered with a short first backoff so faults stay cheap."""

    @hookimpl
    def register_vlm_backends(self, register: Any) -> None:
        from keymps.default_plugins.litellm.backend import LitellmBackend, LitellmOptions

        register(
            "litellm-quick",
            lambda options: LitellmBackend(
                LitellmOptions.model_validate({**options, "backoff_s": BACKOFF_S})
            ),
        )


@pytest.fixture(scope="module")
def server() -> Any:
    from keymps.default_plugins.litellm.backend import import_litellm

    import_litellm()  # seconds, once: not part of any fault's time bound
    with VlmServer(responder=lambda request: json.dumps(DOT)) as running:
        yield running


@pytest.fixture(scope="module")
def task(tmp_path_factory: Any) -> Any:
    path = task_copy(
        tmp_path_factory.mktemp("faults"),
        **{
            "model: openai/gpt-4o": f"model: openai/test-vlm\n  timeout_s: {TIMEOUT_S}\n"
            "  cache: false",
            "Put 15 icing dots": "Put 1 icing dot",
        },
    )
    return keymps.load_task(path)


@pytest.fixture(autouse=True)
def _plugins(keymps_plugins: Any, monkeypatch: Any, tmp_path: Path, server: Any) -> None:
    install(keymps_plugins)
    if not keymps_plugins.manager.has_plugin("quick-retries"):
        keymps_plugins.register(QuickRetries(), name="quick-retries")
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    server.reset()


def run_with(task: Any, api_base: str, out: Path, backend: str = "litellm-quick") -> Any:
    return keymps.run_task(
        task,
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(backend=backend, api_base=api_base, executor="recording", out=out),
    )


def vlm_records(folder: Path) -> list[dict[str, Any]]:
    return [json.loads(p.read_text()) for p in sorted((folder / "vlm").glob("*-attempt*.json"))]


def worst_case_s(faults: int) -> float:
    """What the configuration allows: every try may time out, every wait doubles."""
    waits = sum(min(BACKOFF_S * 2**i, 30.0) for i in range(RETRIES))
    return 2 * (RETRIES + 1) * TIMEOUT_S + waits + 0.6 * faults + 5.0


def closed_port_url() -> tuple[str, str]:
    """An OpenAI-style base URL on a local port nobody listens on, and its HOST:PORT."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    return f"http://127.0.0.1:{port}/v1", f"127.0.0.1:{port}"


@pytest.fixture(scope="module")
def warm(server: Any) -> None:
    """litellm's first completion in a process imports for seconds, past TIMEOUT_S: one call
    outside any bound first (the tests below time what keymps does, not litellm's imports)."""
    from keymps.default_plugins.litellm.backend import import_litellm

    import_litellm().completion(
        model="openai/test-vlm",
        api_base=server.openai_base,
        api_key="no-key-needed",
        messages=[{"role": "user", "content": "warm up"}],
    )


def test_connection_refused_says_so_after_one_quick_retry(
    task: Any, warm: None, tmp_path: Path
) -> None:
    closed, host_port = closed_port_url()
    started = time.perf_counter()
    with pytest.raises(KeympsError) as caught:
        run_with(task, closed, tmp_path / "run", backend="litellm")  # the default backoff
    # one retry after 0.5 s, not 4 tries over 1 + 2 + 4 s of backoff
    assert time.perf_counter() - started < 3.0
    assert_clean_error(caught.value)
    message = str(caught.value)
    assert f"cannot connect to {host_port} (connection refused) after 2 tries" in message
    assert "HTTP 500" not in message and "InternalServerError" not in message
    assert message.count("openai/test-vlm") == 1
    records = vlm_records(tmp_path / "run")
    assert records and not records[-1]["valid"]
    assert f"cannot connect to {host_port}" in records[-1]["errors"][0]
    assert RecordingExecutor.calls == []


class _HtmlPage(BaseHTTPRequestHandler):
    """A web server where the API should be: every POST gets a 200 with an HTML page."""

    requests = 0

    def do_POST(self) -> None:  # noqa: N802 (http.server's naming)
        type(self).requests += 1
        self.rfile.read(int(self.headers.get("content-length", 0)))
        body = b"<!doctype html><html><body><h1>Welcome to nginx!</h1></body></html>"
        self.send_response(200)
        self.send_header("content-type", "text/html")
        self.send_header("content-length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *_: Any) -> None:
        pass


def test_an_html_page_is_not_json_and_not_retried(task: Any, warm: None, tmp_path: Path) -> None:
    page = ThreadingHTTPServer(("127.0.0.1", 0), _HtmlPage)
    thread = threading.Thread(target=page.serve_forever, daemon=True)
    thread.start()
    try:
        port = page.server_address[1]
        with pytest.raises(KeympsError) as caught:
            run_with(task, f"http://127.0.0.1:{port}/v1", tmp_path / "run", backend="litellm")
    finally:
        page.shutdown()
        page.server_close()
    assert_clean_error(caught.value)
    message = str(caught.value)
    assert f"127.0.0.1:{port} answered with an HTML page, not JSON" in message
    assert "planner.api_base" in message and "HTTP 500" not in message
    assert _HtmlPage.requests == 1  # a web page will not turn into an API by asking again


def test_an_answer_with_two_different_objects_is_sent_back_not_read_by_its_first(
    task: Any, server: Any, warm: None, tmp_path: Path
) -> None:
    moved = {**DOT, "pairs": [[[90, 90], [90, 90]]]}
    server.script(Reply.text_answer(f"{json.dumps(moved)}\nOr, better:\n{json.dumps(DOT)}"))
    run = run_with(task, server.openai_base, tmp_path / "run")
    first, second = vlm_records(run.folder)
    assert not first["valid"] and second["valid"]
    assert "2 different JSON objects, and only one is read" in first["errors"][0]
    repair = server.chat_requests[-1].body["messages"][-1]["content"]
    assert "only one is read" in str(repair)
    assert len(RecordingExecutor.calls) == 1  # the repaired answer, not a guess between two
    # the same object twice is one answer
    server.script(Reply.text_answer(f"{json.dumps(DOT)} (again: {json.dumps(DOT)})"))
    again = run_with(task, server.openai_base, tmp_path / "again")
    assert [r["valid"] for r in vlm_records(again.folder)] == [True]


def test_a_server_that_resets_every_connection_is_named(
    task: Any, server: Any, warm: None, tmp_path: Path
) -> None:
    server.script(*[Reply.reset()] * (RETRIES + 1))
    with pytest.raises(KeympsError) as caught:
        run_with(task, server.openai_base, tmp_path / "run")
    assert_clean_error(caught.value)
    host_port = server.openai_base.split("//")[1].split("/")[0]
    message = str(caught.value)
    assert f"failed after 4 tries: connection reset by {host_port} before any answer" in message
    assert "HTTP 500" not in message


def test_missing_credentials_are_not_retried(
    task: Any, warm: None, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # no api_base: litellm would call OpenAI itself, but refuses before any network without a key
    for name in [n for n in os.environ if n.endswith("_API_KEY")]:
        monkeypatch.delenv(name)
    started = time.perf_counter()
    with pytest.raises(KeympsError) as caught:
        keymps.run_task(
            task,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(
                backend="litellm", model="openai/gpt-4o", executor="recording", out=tmp_path / "run"
            ),
        )
    assert time.perf_counter() - started < 2.0  # one try, no backoff (was 4 tries, 18.7 s)
    assert_clean_error(caught.value)
    message = str(caught.value)
    assert "no API key: set OPENAI_API_KEY" in message
    assert message.count("openai/gpt-4o") == 1, message
    assert len(vlm_records(tmp_path / "run")) == 1
    assert RecordingExecutor.calls == []


@pytest.mark.parametrize(
    ("faults", "what"),
    [
        ([Reply.reset()], "reset before any answer"),
        ([Reply.truncated()], "reset mid-answer"),
        ([Reply.broken_json()], "complete response, broken JSON"),
        ([Reply.not_http()], "not HTTP"),
        ([Reply.error(429, retry_after=0.3)], "429 with Retry-After"),
        ([Reply.error(500), Reply.error(502), Reply.error(503)], "5xx three times"),
    ],
    ids=lambda v: v if isinstance(v, str) else "",
)
def test_a_fault_then_a_good_answer_succeeds(
    faults: list[Reply], what: str, task: Any, server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    server.script(*faults)
    started = time.perf_counter()
    try:
        run = run_with(task, server.openai_base, tmp_path / "run")
    except KeympsError as error:
        assert_clean_error(error)
        pytest.fail(f"{what}: a retry should have succeeded, got: {error}")
    elapsed = time.perf_counter() - started
    fuzz_counter.add("VLM faults/named", what, "recovered")
    assert elapsed < worst_case_s(len(faults))
    if what == "429 with Retry-After":
        assert elapsed >= 0.3, "the server's Retry-After is honoured"
    assert len(server.chat_requests) == len(faults) + 1
    assert len(RecordingExecutor.calls) == 1
    records = vlm_records(run.folder)
    assert records[-1]["valid"] and records[-1]["latency_s"] > 0
    assert len(records[-1]["retries"]) == len(faults)  # each failed try, and the wait after it
    assert all("retried after" in line for line in records[-1]["retries"])


@pytest.mark.parametrize(
    ("faults", "expected"),
    [
        ([Reply.error(500)] * 4, "failed after 4 tries"),
        ([Reply.reset()] * 4, "failed after 4 tries: connection reset by 127.0.0.1:"),
        ([Reply.text_answer(json.dumps(DOT), delay_s=2.0)], "no answer within 0.6 s"),
        ([Reply.error(401, message="bad key")], "rejected the credentials"),
        ([Reply.error(404, message="no such model")], "not found"),
        ([Reply.error(400, message="image too large")], "refused the request"),
    ],
    ids=["5xx", "resets", "slow", "401", "404", "400"],
)
def test_faults_that_persist_end_in_one_clean_line(
    faults: list[Reply], expected: str, task: Any, server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    server.script(*faults)
    started = time.perf_counter()
    with pytest.raises(KeympsError) as caught:
        run_with(task, server.openai_base, tmp_path / "run")
    assert time.perf_counter() - started < worst_case_s(len(faults))
    assert_clean_error(caught.value)
    assert expected in str(caught.value)
    fuzz_counter.add("VLM faults/named", expected, "clean error")
    assert RecordingExecutor.calls == []
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["ok"] is False and expected in record["error"]
    assert expected in vlm_records(tmp_path / "run")[-1]["errors"][0]


def _body(text: str, **fields: Any) -> bytes:
    return json.dumps({"choices": [{"message": {"content": text}}], **fields}).encode()


NAMED_FAILURES = {
    "not utf-8": (
        [Reply.raw(_body("x").replace(b'"x"', b'"\xff\xfe"'))],
        "answered with bytes that are not UTF-8 text",
        1,
    ),
    "server-sent events": (
        [
            Reply.raw(
                b'data: {"choices": [{"delta": {"content": "hi"}}]}\n\ndata: [DONE]\n\n',
                {"Content-Type": "text/event-stream"},
            )
        ],
        "answered with a stream of server-sent events, though keymps asked for one JSON answer",
        1,
    ),
    "server-sent events, labelled JSON": (
        [Reply.raw(b'data: {"choices": [{"delta": {"content": "hi"}}]}\n\ndata: [DONE]\n\n')],
        "answered with a stream of server-sent events, though keymps asked for one JSON answer",
        1,
    ),
    "bad chunks": (
        [Reply.bad_chunks()] * (RETRIES + 1),
        "sent a malformed chunked answer",
        RETRIES + 1,
    ),
    "301 to a GET": (
        [Reply.redirect(301, "/v2/chat/completions")],
        "redirected the request (HTTP 301) to http://127.0.0.1:{port}/v2/chat/completions, which "
        "turned the POST into a GET: set planner.api_base to http://127.0.0.1:{port}/v2",
        1,
    ),
    "5000 digits": (
        [Reply.raw(_body("x", usage={"prompt_tokens": 7}).replace(b"7", b"9" * 5000))],
        "answered with a number of over 4300 digits",
        1,
    ),
    "400": (
        [Reply.error(400, message="image too large")],
        "(openai/test-vlm at http://127.0.0.1:{port}/v1) refused the request",
        1,
    ),
}


@pytest.mark.parametrize("name", sorted(NAMED_FAILURES))
def test_failures_litellm_calls_http_500_are_named(
    name: str, task: Any, server: Any, warm: None, tmp_path: Path, fuzz_counter: Any
) -> None:
    """Before: all but the 400 read "failed after 4 tries (the last one: HTTP 500)" with
    litellm's text (Python's own int-conversion advice among them), and the 400 named no
    server."""
    replies, expected, tries = NAMED_FAILURES[name]
    server.script(*replies)
    with pytest.raises(KeympsError) as caught:
        run_with(task, server.openai_base, tmp_path / "run")
    assert_clean_error(caught.value)
    message = str(caught.value)
    assert expected.format(port=server.port) in message
    assert "HTTP 500" not in message and "set_int_max_str_digits" not in message
    assert len(server.chat_requests) == tries
    assert RecordingExecutor.calls == []
    fuzz_counter.add("VLM faults/named", name, "clean error")


def test_a_redirect_that_keeps_the_post_is_followed(
    task: Any, server: Any, warm: None, tmp_path: Path
) -> None:
    server.script(Reply.redirect(307, "/v2/chat/completions"))
    run_with(task, server.openai_base, tmp_path / "run")
    assert [r.path for r in server.chat_requests[-2:]] == [
        "/v1/chat/completions",
        "/v2/chat/completions",
    ]
    assert len(RecordingExecutor.calls) == 1


CUT_OFF = json.dumps(DOT)[:30]
TOOL_CALL = {"id": "call_1", "type": "function", "function": {"name": "draw", "arguments": "{}"}}


@pytest.mark.parametrize(
    ("ended", "expected"),
    [
        (
            Reply.ended(CUT_OFF, "length"),
            "the answer stopped at the model's output token limit (finish_reason 'length') "
            "before it was complete: raise planner.max_tokens (unset: the server's own limit)",
        ),
        (Reply.ended(None, "stop", refusal="I can't help with that."), 'the model refused: "I'),
        (
            Reply.ended(None, "tool_calls", tool_calls=[TOOL_CALL]),
            "the model called a tool instead of answering in text",
        ),
        (Reply.ended("", "content_filter"), "the provider's content filter stopped the answer"),
    ],
    ids=["length", "refusal", "tool call", "content filter"],
)
def test_an_answer_that_ended_early_says_why(
    ended: Reply, expected: str, task: Any, server: Any, warm: None, tmp_path: Path
) -> None:
    """Before: all four read "no JSON object" (or broken JSON), which sent users looking at
    their prompt instead of the server's token limit or the model's refusal."""
    server.script(ended, ended)
    with pytest.raises(KeympsError) as caught:
        run_with(task, server.openai_base, tmp_path / "run")
    assert_clean_error(caught.value)
    message = str(caught.value)
    assert expected in message and "no valid combined answer in 2 attempt(s)" in message
    assert RecordingExecutor.calls == []
    first, second = vlm_records(tmp_path / "run")
    assert expected in first["errors"][0] and expected in second["errors"][0]
    repair = str(server.chat_requests[-1].body["messages"][-1]["content"])
    assert expected.replace('"', "'")[:40] in repair.replace('"', "'")  # the model is told
    assert "max_tokens" not in server.chat_requests[-1].body  # unset: the server's own limit


def test_planner_max_tokens_is_sent_and_named_when_reached(
    task: Any, server: Any, warm: None, tmp_path: Path
) -> None:
    limited = task.model_copy(
        update={"planner": task.planner.model_copy(update={"max_tokens": 300})}
    )
    server.script(Reply.ended(CUT_OFF, "length"), Reply.json_answer(DOT))
    run = run_with(limited, server.openai_base, tmp_path / "run")
    assert [r.body.get("max_tokens") for r in server.chat_requests[-2:]] == [300, 300]
    first, second = vlm_records(run.folder)
    assert "raise planner.max_tokens (now 300)" in first["errors"][0] and second["valid"]
    assert len(RecordingExecutor.calls) == 1


FAULTS = {
    "reset": Reply.reset(),
    "truncated": Reply.truncated(),
    "broken json": Reply.broken_json(),
    "not http": Reply.not_http(),
    "429": Reply.error(429, retry_after=0.05),
    "500": Reply.error(500),
    "503 retry-after 0": Reply.error(503, retry_after=0),
    "slow": Reply.text_answer(json.dumps(DOT), delay_s=TIMEOUT_S + 0.4),
    "garbage answer": Reply.text_answer("I would rather not."),
    "good": Reply.json_answer(DOT),
}


@settings(deadline=None, max_examples=20, suppress_health_check=list(HealthCheck), database=None)
@given(sequence=st.lists(st.sampled_from(sorted(FAULTS)), min_size=1, max_size=5))
def test_random_fault_sequences(
    sequence: list[str], task: Any, server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    server.reset()
    RecordingExecutor.calls = []
    server.script(*(FAULTS[name] for name in sequence))
    out = tmp_path / f"run-{time.monotonic_ns()}"
    started = time.perf_counter()
    try:
        run_with(task, server.openai_base, out)
    except KeympsError as error:
        assert_clean_error(error)
        assert RecordingExecutor.calls == []
        assert vlm_records(out), "the run folder records the failed attempt"
        outcome = "clean error"
    else:
        assert len(RecordingExecutor.calls) == 1
        outcome = "recovered"
    assert time.perf_counter() - started < worst_case_s(len(sequence))
    fuzz_counter.add("VLM faults/random sequences", tuple(sequence), outcome)
