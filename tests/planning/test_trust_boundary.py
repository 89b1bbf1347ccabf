"""Attacks on the VLM path by a hostile task file or server, on 127.0.0.1 (docs/security.md).

A shared task file tries to send the user's key to its own server, to name any environment
variable as its key, and to read /proc, /dev, sockets, links out of its folder or huge files
into the prompt; a server trickles its answer one byte a second past planner.timeout_s. Every
case ends in a correct keyless run or one clean located line, nothing executes after an error
(the recording executor stands in for the robot), and no request outlives its deadline. The
cases are counted in the fuzz summary (suite "VLM attacks/...").
"""

from __future__ import annotations

import asyncio
import json
import os
import secrets
import shutil
import socket
import string
import subprocess
import sys
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from helpers.budget import Budget
from helpers.fuzz_support import (
    REPO,
    RecordingExecutor,
    assert_clean_error,
    install,
    plan_request,
    task_copy,
)
from helpers.vlm_server import Reply, VlmServer
from hypothesis import given, settings
from hypothesis import strategies as st

import keymps
from keymps.cli.app import cli
from keymps.errors import KeympsError, TaskFileError
from keymps.run import RunOptions, RunOverrides

DOT = {"keyword": "line", "pairs": [[[130, 130], [130, 130]]], "rationale": "one dot"}
CANARY = "sk-attack-" + secrets.token_hex(10)
DEADLINE_S = 1.0


@pytest.fixture(scope="module")
def server() -> Any:
    from keymps.default_plugins.litellm.backend import import_litellm

    import_litellm()  # seconds, once: not part of any time bound
    with VlmServer(responder=lambda request: json.dumps(DOT)) as running:
        yield running


@pytest.fixture(autouse=True)
def _isolated(keymps_plugins: Any, monkeypatch: Any, tmp_path: Path, server: Any) -> None:
    install(keymps_plugins)
    RecordingExecutor.calls = []
    monkeypatch.setenv("OPENAI_API_KEY", CANARY)
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("KEYMPS_CONFIG", str(tmp_path / "user-config.yaml"))
    server.reset()


def hostile_task(folder: Path, planner: str = "", prompt: str | None = None) -> Path:
    """cake_icing with `planner` lines added to its planner section; `prompt` replaces its
    planner.prompt ("" drops it: the prompt is then looked for in the search folders)."""
    lines = "model: openai/test-vlm\n  cache: false"
    if planner:
        lines += "\n  " + planner.replace("\n", "\n  ")
    if prompt is not None:
        lines += f"\n  prompt: {prompt}" if prompt else ""
    path = task_copy(folder, **{"model: openai/gpt-4o": lines, "Put 15 icing dots": "Put 1"})
    # the scene beside the task: a task-only server is sent no image from outside its folder
    shutil.copy(REPO / "tasks/scenes/round_cake.png", folder / "round_cake.png")
    path.write_text(
        path.read_text().replace(f"{REPO}/tasks/scenes/round_cake.png", "round_cake.png")
    )
    if prompt is not None:
        path.write_text(path.read_text().replace(f"  prompt: {REPO}/prompts/icing.md\n", ""))
    return path


def run(task: Path | Any, out: Path, **given: Any) -> Any:
    options = {k: given.pop(k) for k in ("record", "no_cache") if k in given}
    return keymps.run_task(
        task,
        options=RunOptions(rerun="off", **options),
        overrides=RunOverrides(executor="recording", out=out, **given),
    )


def authorization(server: Any) -> list[str]:
    return [r.headers.get("authorization", "") for r in server.chat_requests]


# ----------------------------------------------------------------------------- trust boundary


def test_an_api_base_only_the_task_names_gets_no_key_and_the_run_says_so(
    server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    task = hostile_task(tmp_path, f"api_base: {server.openai_base}")
    with pytest.warns(UserWarning, match="no API key is sent"):
        finished = run(task, tmp_path / "run")
    assert authorization(server) == ["Bearer no-key-needed"]  # a keyless local server works
    assert len(RecordingExecutor.calls) == 1
    record = json.loads((finished.folder / "run.json").read_text())
    warning = [w for w in record["warnings"] if "no API key is sent" in w]
    assert len(warning) == 1 and "task.yaml:" in warning[0] and "--api-base" in warning[0]
    fuzz_counter.add("VLM attacks/trust", "task-only api_base", "keyless run")


@pytest.mark.parametrize(
    "key_env", [None, "LAB_VLM_API_KEY"], ids=["provider variable", "planner.api_key_env"]
)
def test_the_users_own_api_base_gets_the_key(
    key_env: str | None, server: Any, tmp_path: Path, monkeypatch: Any, fuzz_counter: Any
) -> None:
    expected = CANARY
    planner = f"api_base: {server.openai_base}"
    if key_env:
        expected = "lab-" + secrets.token_hex(8)
        monkeypatch.setenv(key_env, expected)
        planner += f"\napi_key_env: {key_env}"
    task = hostile_task(tmp_path, planner)
    run(task, tmp_path / "cli", api_base=server.openai_base)  # --api-base: the user's choice
    (tmp_path / "user-config.yaml").write_text(f"trusted_api_bases: [{server.url}]\n")
    run(task, tmp_path / "config")  # listed in the user's own config (a path below it)
    assert authorization(server) == [f"Bearer {expected}"] * 2
    fuzz_counter.add("VLM attacks/trust", ("user api_base", key_env), "key sent")


@pytest.mark.parametrize(
    "trusted",
    ["http://127.0.0.1:1/v1", "https://127.0.0.1:{port}/v1", "http://127.0.0.1:{port}/other"],
    ids=["other port", "other scheme", "other path"],
)
def test_a_trusted_entry_covers_only_its_own_server(
    trusted: str, server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    (tmp_path / "user-config.yaml").write_text(
        f"trusted_api_bases: ['{trusted.format(port=server.port)}']\n"
    )
    task = hostile_task(tmp_path, f"api_base: {server.openai_base}")
    with pytest.warns(UserWarning, match="no API key is sent"):
        run(task, tmp_path / "run")
    assert authorization(server) == ["Bearer no-key-needed"]
    fuzz_counter.add("VLM attacks/trust", ("near-miss trusted entry", trusted), "keyless run")


@pytest.mark.parametrize("climb", ["x/..", "x/./..", "x/%2e%2e"])
def test_dot_segments_do_not_climb_out_of_a_trusted_path(
    climb: str, server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    """'/v1/x/..' is below a trusted '/v1/x' as text and is '/v1' once resolved: a stranger's
    task file sent the key to a sibling path of the trusted one."""
    (tmp_path / "user-config.yaml").write_text(f"trusted_api_bases: ['{server.openai_base}/x']\n")
    task = hostile_task(tmp_path, f"api_base: {server.openai_base}/{climb}")
    with pytest.warns(UserWarning, match="no API key is sent"):
        run(task, tmp_path / "run")
    assert all(header == "Bearer no-key-needed" for header in authorization(server))
    fuzz_counter.add("VLM attacks/trust", ("dot segments", climb), "keyless run")


def test_the_providers_own_endpoint_is_trusted_from_a_task_file(tmp_path: Path) -> None:
    from keymps.planning.backend_choice import api_base_trusted

    def trusted(model: str, api_base: str) -> bool:
        task = hostile_task(tmp_path, f"api_base: {api_base}")
        text = task.read_text().replace("openai/test-vlm", model)
        task.write_text(text)
        return api_base_trusted(keymps.load_task(task))

    assert trusted("openai/gpt-4o", "https://api.openai.com/v1")
    assert trusted("anthropic/claude-sonnet-4-5", "https://api.anthropic.com")
    assert not trusted("openai/gpt-4o", "http://api.openai.com/v1")  # not https
    assert not trusted("anthropic/claude-sonnet-4-5", "https://api.openai.com/v1")
    assert not trusted("openai/gpt-4o", "https://api.openai.com.evil.example/v1")


def test_a_cloud_signed_provider_refuses_a_task_only_api_base(server: Any, tmp_path: Path) -> None:
    task = hostile_task(tmp_path, f"api_base: {server.openai_base}")
    task.write_text(task.read_text().replace("openai/test-vlm", "bedrock/anthropic.claude-v2"))
    with pytest.raises(KeympsError) as caught, pytest.warns(UserWarning):
        run(task, tmp_path / "run", backend="litellm")
    assert_clean_error(caught.value)
    assert "signs every request with your cloud credentials" in str(caught.value)
    assert server.chat_requests == [] and RecordingExecutor.calls == []


@pytest.mark.parametrize(
    ("name", "allowed"),
    [
        ("AWS_SECRET_ACCESS_KEY", False),
        ("GITHUB_TOKEN", False),
        ("HOME", False),
        ("MY_VLM_KEY", False),
        ("OPENAI_API_KEY", True),
        ("LAB_VLM_API_KEY", True),
        ("REPLICATE_API_TOKEN", True),
        ("HF_TOKEN", True),
    ],
)
def test_api_key_env_names_only_provider_key_variables(
    name: str, allowed: bool, tmp_path: Path, fuzz_counter: Any
) -> None:
    task = hostile_task(tmp_path, f"api_key_env: {name}")
    line = next(i for i, t in enumerate(task.read_text().splitlines(), 1) if "api_key_env" in t)
    if allowed:
        keymps.load_task(task)
    else:
        with pytest.raises(TaskFileError) as caught:
            keymps.load_task(task)
        assert caught.value.problems[0].startswith(f"{task}:{line}:16: planner.api_key_env:")
        assert "not a provider key variable" in caught.value.problems[0]
    fuzz_counter.add("VLM attacks/api_key_env", name, "accepted" if allowed else "refused")


def test_the_user_config_allows_further_key_names(tmp_path: Path) -> None:
    task = hostile_task(tmp_path, "api_key_env: MY_VLM_KEY")
    (tmp_path / "user-config.yaml").write_text("api_key_envs: [MY_VLM_KEY]\n")
    assert keymps.load_task(task).planner.api_key_env == "MY_VLM_KEY"
    (tmp_path / "user-config.yaml").write_text("api_key_envs: [1 2]\ntrusted: []\n")
    with pytest.raises(
        KeympsError,
        match=r"user-config.yaml:1:15: api_key_envs: .1 2. is not an environment variable",
    ):
        keymps.load_task(task)


# ----------------------------------------------------------------------- files a task reads


def _fifo(folder: Path) -> Path:
    path = folder / "prompt.fifo"
    os.mkfifo(path)
    return path


def _socket(folder: Path) -> Path:
    path = folder / "prompt.sock"
    listener = socket.socket(socket.AF_UNIX)
    listener.bind(str(path))
    listener.close()
    return path


def _link(folder: Path, target: str) -> Path:
    path = folder / "linked.md"
    path.symlink_to(target)
    return path


def _loop(folder: Path) -> Path:
    (folder / "a.md").symlink_to(folder / "b.md")
    (folder / "b.md").symlink_to(folder / "a.md")
    return folder / "a.md"


def _huge(folder: Path) -> Path:
    path = folder / "huge.md"
    path.write_bytes(b"x" * (256 * 1024 + 1))
    return path


PROMPTS = {
    "/proc/self/environ": (lambda folder: Path("/proc/self/environ"), "kernel or device file"),
    "/dev/zero": (lambda folder: Path("/dev/zero"), "kernel or device file"),
    "/etc/passwd": (lambda folder: Path("/etc/passwd"), "outside the task's folder"),
    "../../ escape": (lambda folder: folder / ".." / ".." / "secret.md", "outside"),
    "fifo": (_fifo, "not a regular file"),
    "socket": (_socket, "not a regular file"),
    "link to /proc": (lambda folder: _link(folder, "/proc/self/environ"), "kernel or device"),
    "link out of the folder": (lambda folder: _link(folder, "/etc/hostname"), "outside"),
    "symlink loop": (_loop, "cannot resolve"),
    "257 KiB": (_huge, "bytes, more than the 262144"),
    "missing": (lambda folder: folder / "nowhere.md", "file not found"),
}


@pytest.mark.parametrize("case", sorted(PROMPTS))
def test_a_prompt_the_task_names_must_be_a_small_file_in_its_folder(
    case: str, tmp_path: Path, fuzz_counter: Any
) -> None:
    folder = tmp_path / "shared" / "task"
    folder.mkdir(parents=True)
    (tmp_path / "secret.md").write_text("the lab's secrets")
    make, expected = PROMPTS[case]
    prompt = make(folder)
    task = hostile_task(folder, prompt=str(prompt))
    result = CliRunner().invoke(cli, ["validate", str(task)])
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and f"{task}:" in lines[0] and "planner.prompt:" in lines[0], lines
    assert expected in lines[0]
    with pytest.raises(KeympsError) as caught:
        run(task, tmp_path / "run")
    assert_clean_error(caught.value)
    assert RecordingExecutor.calls == []
    fuzz_counter.add("VLM attacks/task files", ("prompt", case), "located error")


@pytest.mark.parametrize(
    ("written", "expected"),
    [(r'"a\nb.md"', "file not found: '"), (r'"a\0b.md"', "not a valid file name: '")],
)
def test_a_prompt_name_with_a_newline_or_a_nul_is_refused_in_one_located_line(
    written: str, expected: str, tmp_path: Path
) -> None:
    """YAML's escapes put any character in a name: the message quotes it (no second line), and
    a NUL, which no file name can hold, is refused rather than crashing the path lookup."""
    task = hostile_task(tmp_path / "task", prompt=written)
    result = CliRunner().invoke(cli, ["validate", str(task)])
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "planner.prompt:" in lines[0] and expected in lines[0], lines
    with pytest.raises(KeympsError) as caught:
        run(task, tmp_path / "run")
    assert_clean_error(caught.value)
    assert RecordingExecutor.calls == []


@pytest.mark.parametrize(
    ("case", "expected"),
    [("link to /dev/zero", "kernel or device"), ("link out", "outside"), ("fifo", "regular")],
)
def test_prompts_and_primitives_found_in_the_task_folder_are_checked_too(
    case: str, expected: str, tmp_path: Path, fuzz_counter: Any
) -> None:
    for kind, name in (("prompts", "icing.md"), ("primitives", "line.yaml")):
        folder = tmp_path / kind / "task"
        (folder / kind).mkdir(parents=True)
        found = folder / kind / name
        if case == "fifo":
            os.mkfifo(found)
        else:
            found.symlink_to("/dev/zero" if case == "link to /dev/zero" else "/etc/hostname")
        task = hostile_task(folder, prompt="")
        result = CliRunner().invoke(cli, ["validate", str(task)])
        assert result.exit_code == 1 and expected in result.output, result.output
        assert name in result.output and len(result.output.strip().splitlines()) == 1
        with pytest.raises(KeympsError) as caught:
            run(task, tmp_path / f"run-{kind}")
        assert_clean_error(caught.value)
        fuzz_counter.add("VLM attacks/task files", (kind, case), "located error")
    assert RecordingExecutor.calls == []


def test_the_shipped_layout_still_validates(tmp_path: Path) -> None:
    for name in ("cake_icing.yaml", "object_cutting.yaml"):  # prompt: ../prompts/NAME.md
        result = CliRunner().invoke(cli, ["validate", str(REPO / "tasks" / name)])
        assert result.exit_code == 0, result.output


# ------------------------------------------------------------------------------ deadlines


@pytest.fixture
def deadline_task(tmp_path: Path) -> Any:
    path = hostile_task(tmp_path, f"timeout_s: {DEADLINE_S}")
    return keymps.load_task(path)


@pytest.mark.parametrize("interval_s", [0.3, 1.0], ids=["byte every 0.3 s", "byte every 1 s"])
def test_a_trickling_server_is_stopped_at_the_deadline(
    interval_s: float, deadline_task: Any, server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    server.script(Reply.trickle(interval_s))
    started = time.perf_counter()
    with pytest.raises(KeympsError) as caught:
        run(deadline_task, tmp_path / "run", api_base=server.openai_base)
    elapsed = time.perf_counter() - started
    assert_clean_error(caught.value)
    assert f"no answer within {DEADLINE_S:g} s (planner.timeout_s)" in str(caught.value)
    assert elapsed < DEADLINE_S + 1.5, f"{elapsed:.2f} s"
    assert len(server.chat_requests) == 1  # a deadline is not retried
    assert RecordingExecutor.calls == []
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["ok"] is False and "planner.timeout_s" in record["error"]
    fuzz_counter.add("VLM attacks/deadlines", ("trickle, run", interval_s), "stopped in time")


def test_the_async_call_of_keymps_eval_has_the_same_deadline(
    server: Any, fuzz_counter: Any
) -> None:
    from keymps.default_plugins.litellm.backend import LitellmBackend, LitellmOptions

    backend = LitellmBackend(
        LitellmOptions(model="openai/test-vlm", api_base=server.openai_base, timeout_s=DEADLINE_S)
    )
    request = plan_request(DEADLINE_S)
    server.script(Reply.trickle(0.2))
    started = time.perf_counter()
    with pytest.raises(KeympsError, match="no answer within 1 s"):
        asyncio.run(backend.acomplete(request))
    assert time.perf_counter() - started < DEADLINE_S + 1.0
    fuzz_counter.add("VLM attacks/deadlines", "trickle, async", "stopped in time")


def test_validate_and_run_say_in_one_line_that_no_key_is_sent(
    server: Any, tmp_path: Path, monkeypatch: Any
) -> None:
    task = hostile_task(tmp_path, f"api_base: {server.openai_base}")
    checked = CliRunner().invoke(cli, ["validate", str(task)])
    assert checked.exit_code == 0, checked.output
    notes = [line for line in checked.output.splitlines() if "no API key is sent" in line]
    assert len(notes) == 1 and notes[0].startswith(f"note: {task}:")
    with pytest.warns(UserWarning, match="no API key is sent"):
        ran = CliRunner().invoke(cli, ["run", str(task), "--executor", "file", "--rerun", "off"])
    assert ran.exit_code == 0, ran.output
    assert sum("no API key is sent" in line for line in ran.output.splitlines()) == 1


# ------------------------------------------------------------------------------ redaction


def test_the_redactor_removes_secrets_by_value(monkeypatch: Any) -> None:
    from keymps.planning.redaction import redact, redact_text, remember

    monkeypatch.setenv("SOME_ODD_KEY", "odd-value-123")
    monkeypatch.setenv("LAB_PASSWORD", "hunter2hunter2")
    monkeypatch.setenv("FOO_TOKEN", "x")  # short and never used: left alone
    monkeypatch.setenv("KEYMPS_CACHE_DIR", "/tmp/not-a-secret-folder")
    remember("k3y")  # a key a backend used: any length
    text = (
        "odd-value-123 hunter2hunter2 k3y x /tmp/not-a-secret-folder "
        "http://lab:pw@host/v1 https://h/v1?key=AIzaQ&alt=json&api_key=abc "
        + json.dumps({"quoted": 'odd-value-123"'})
    )
    assert redact_text(text) == (
        "[redacted] [redacted] [redacted] x /tmp/not-a-secret-folder "
        "http://[redacted]@host/v1 https://h/v1?key=[redacted]&alt=json&api_key=[redacted] "
        '{"quoted": "[redacted]\\""}'
    )
    record = {"headers": {"Authorization": "Bearer zz"}, "prompt_tokens": 3, "errors": ["k3y"]}
    assert redact(record) == {
        "headers": {"Authorization": "[redacted]"},
        "prompt_tokens": 3,
        "errors": ["[redacted]"],
    }


def test_credentials_in_an_api_base_are_redacted_wherever_they_appear() -> None:
    from keymps.planning.redaction import redact_text, remember, url_secrets

    secret = "pw" + secrets.token_hex(6)
    remember(*url_secrets(f"http://lab:{secret}@127.0.0.1:9/v1?api_key=q{secret}"))
    assert redact_text(f"the server said lab:{secret} and q{secret}") == (
        "the server said [redacted] and [redacted]"
    )


@pytest.mark.parametrize(
    "before", ["", " ", "(", "1", "x", "a.b-", "_", "@", "é", "said:"], ids=repr
)
def test_url_userinfo_is_redacted_whatever_stands_before_the_scheme(before: str) -> None:
    from keymps.planning.redaction import redact_text

    text = redact_text(f"{before}https://lab:pw-zz@h/v1 and {before}ftp://u@h", [])
    assert "pw-" not in text and "u@h" not in text, text
    assert text.count("[redacted]@h") == 2


HOSTILE_SHAPES = {
    "a word": "a" * 400_000,
    "digits and letters": "1a" * 200_000,
    "dots": "a." * 200_000,
    "a scheme with no userinfo end": "a://" + "b" * 400_000,
    "a query name": "?" + "w" * 400_000,
    "query parameters": "?key=" * 80_000,
}


@pytest.mark.parametrize("text", HOSTILE_SHAPES.values(), ids=HOSTILE_SHAPES.keys())
def test_redacting_a_huge_hostile_answer_takes_linear_time(text: str) -> None:
    """Every answer is redacted before it is checked: a server's 2 MB answer of one long word
    took minutes when the URL pattern was tried from each of its letters. Linear, 400 k
    characters take milliseconds; the bound is generous so that only a quadratic search fails."""
    from keymps.planning.redaction import redact_text

    budget = Budget()
    redact_text(text, ["a-secret-of-this-test"])
    budget.check(3.0)


KEYISH = st.text(
    alphabet=st.sampled_from(string.ascii_uppercase + 'bfghijklmnopqsuvwxyz0123456789-_.+=/"\\é'),
    min_size=3,
    max_size=40,
)
"""Key-like text (quotes, backslashes, a non-ASCII letter: JSON escapes them), sharing no
character with '[redacted]' so that a leftover could not hide inside the replacement."""


@settings(max_examples=200, deadline=None, database=None)
@given(key=KEYISH, before=st.text(max_size=30), after=st.text(max_size=30))
def test_a_used_key_of_any_form_never_survives_into_a_record(
    key: str, before: str, after: str, fuzz_counter: Any
) -> None:
    from keymps.planning import redaction

    saved = set(redaction._remembered)
    try:
        redaction.remember(key)
        record = {"rationale": before + key + after, "calls": [{"answer": json.dumps(key)}]}
        redacted = redaction.redact(record)
        texts = [redacted["rationale"], redacted["calls"][0]["answer"]]
        for form in (key, json.dumps(key)[1:-1], json.dumps(key, ensure_ascii=False)[1:-1]):
            assert all(form not in text for text in texts)  # what any JSON reader gets back
    finally:
        redaction._remembered.clear()
        redaction._remembered.update(saved)
    fuzz_counter.add("VLM attacks/redaction", (key, before, after), "no leak")


@settings(max_examples=200, deadline=None, database=None)
@given(
    user=st.text(string.ascii_letters + string.digits, min_size=1, max_size=12),
    password=st.text(string.ascii_letters + string.digits + "-_~", min_size=1, max_size=24),
    parameter=st.sampled_from(["api_key", "key", "token", "access_token", "apikey", "sig"]),
    value=st.text(string.ascii_letters + string.digits + "-_", min_size=1, max_size=24),
)
def test_url_credentials_are_redacted_in_any_text(
    user: str, password: str, parameter: str, value: str, fuzz_counter: Any
) -> None:
    from keymps.planning.redaction import redact_text

    url = f"https://{user}:{password}@vlm.example.org:8443/v1?alt=json&{parameter}={value}"
    shown = redact_text(f"cannot connect to {url}: refused")
    assert shown == (
        "cannot connect to https://[redacted]@vlm.example.org:8443/v1?alt=json&"
        f"{parameter}=[redacted]: refused"
    )
    fuzz_counter.add("VLM attacks/redaction", url, "no leak")


@pytest.mark.parametrize("seed", range(4))
def test_random_trickles_never_outlive_the_deadline(
    seed: int, server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    import random

    from keymps.default_plugins.litellm.backend import LitellmBackend, LitellmOptions

    rng = random.Random(seed)
    deadline = rng.uniform(0.4, 1.2)
    interval = rng.uniform(0.02, 0.6)
    backend = LitellmBackend(
        LitellmOptions(model="openai/test-vlm", api_base=server.openai_base, timeout_s=deadline)
    )
    server.script(Reply.trickle(interval))
    started = time.perf_counter()
    with pytest.raises(KeympsError, match=r"planner\.timeout_s"):
        backend.complete(plan_request(deadline))
    assert time.perf_counter() - started < deadline + 0.5
    fuzz_counter.add("VLM attacks/deadlines", ("trickle", deadline, interval), "stopped in time")


def test_folders_other_users_may_write_are_not_searched_outside_the_task(tmp_path: Path) -> None:
    """A task in /tmp/x looked in /tmp/primitives first: anyone could plant a primitive there.
    A world-writable ../primitives, or one another user owns, is left out; the task's own
    primitives/ and the bundled dictionary stay."""
    import os

    from keymps.config.trust import prompt_search_dirs
    from keymps.primitives.dictionary import BUNDLED_DIR, default_search_dirs

    task_folder = tmp_path / "task"
    task_folder.mkdir()
    shared = tmp_path / "primitives"
    shared.mkdir()
    (shared / "straight.yaml").write_text("planted")
    prompts = tmp_path / "prompts"
    prompts.mkdir()
    assert shared.resolve() in default_search_dirs(task_folder)  # ours: searched
    shared.chmod(0o777)
    prompts.chmod(0o777)
    searched = default_search_dirs(task_folder)
    assert shared.resolve() not in searched and BUNDLED_DIR.resolve() in searched
    assert (task_folder / "primitives").resolve() in searched
    assert prompts not in prompt_search_dirs(task_folder)
    shared.chmod(0o755)
    if os.geteuid() == 0:  # only root can make a folder another user's (CI runs as root)
        os.chown(shared, 12345, 12345)
        assert shared.resolve() not in default_search_dirs(task_folder)


# ----------------------------------------------------------------------------- answer size

BOMB_MB = 512


def _compressed(chunks: list[bytes] | bytes, wbits: int = 16 + zlib.MAX_WBITS) -> bytes:
    """gzip (default), zlib (wbits 15) or raw deflate (-15) of the chunks, as one stream."""
    compressor = zlib.compressobj(1, zlib.DEFLATED, wbits)
    parts = [compressor.compress(c) for c in ([chunks] if isinstance(chunks, bytes) else chunks)]
    return b"".join([*parts, compressor.flush()])


@pytest.fixture(scope="module")
def gzip_bomb() -> bytes:
    """512 MB of zeros inside a completion's content, as 2.3 MB of gzip (built in about 0.6 s)."""
    zeros = bytes(2**20)
    return _compressed([b'{"choices": [{"message": {"content": "', *[zeros] * BOMB_MB])


def _completion(text: str) -> bytes:
    from helpers.vlm_server import _openai_completion

    return json.dumps(_openai_completion(text, "test-vlm")).encode()


CHILD_RUN = """
import json, sys, time
import keymps
from keymps.errors import KeympsError
started, error = time.perf_counter(), None
try:
    task = keymps.load_task(sys.argv[1])
    keymps.run_task(
        task,
        options=keymps.RunOptions(rerun="off"),
        overrides=keymps.RunOverrides(api_base=sys.argv[2], out=sys.argv[3], executor="sim"),
    )
except KeympsError as caught:
    error = str(caught)
# VmHWM: this process's own peak (ru_maxrss would start from the forking parent's size)
status = open("/proc/self/status").read().split("VmHWM:")[1]
peak_mb = int(status.split()[0]) / 1024
print(json.dumps({"error": error, "peak_mb": peak_mb, "s": time.perf_counter() - started}))
"""


def test_a_gzip_bomb_is_refused_after_8_mb_in_little_memory(
    server: Any, gzip_bomb: bytes, tmp_path: Path, fuzz_counter: Any
) -> None:
    """Before: a bomb was inflated and read whole, and the call tried 4 times (a 1 GB bomb took
    one try to 2.3 GB). The run is a child process, so that its peak memory is its own."""
    server.script(Reply.raw(gzip_bomb, {"Content-Encoding": "gzip"}))
    done = subprocess.run(
        [
            sys.executable,
            "-c",
            CHILD_RUN,
            str(hostile_task(tmp_path)),
            server.openai_base,
            str(tmp_path / "run"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    outcome = json.loads(done.stdout.strip().splitlines()[-1])
    assert f"127.0.0.1:{server.port} sent an answer larger than 8 MB: refused unread" in (
        outcome["error"] or ""
    )
    assert len(server.chat_requests) == 1  # not retried
    assert outcome["peak_mb"] < 600, outcome  # litellm and the run alone: about 300 MB
    fuzz_counter.add("VLM attacks/answer size", "gzip bomb, 512 MB", "refused unread")


HUGE_OR_UNREADABLE = {
    "40 MB, plain": (Reply.raw(b" " * 40 * 2**20), "sent an answer larger than 8 MB"),
    "brotli": (
        Reply.raw(b"\x1b\x03\x00", {"Content-Encoding": "br"}),
        "sent its answer compressed as 'br', which keymps did not ask for",
    ),
    "gzip twice": (
        Reply.raw(_compressed(_compressed(b"{}")), {"Content-Encoding": "gzip, gzip"}),
        "compressed as 'gzip, gzip'",
    ),
    "corrupt gzip": (
        Reply.raw(  # a gzip header, then a deflate block of the reserved type 3
            b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\x03\xff\xff\xff", {"Content-Encoding": "gzip"}
        ),
        "sent corrupt gzip data",
    ),
}


@pytest.mark.parametrize("name", sorted(HUGE_OR_UNREADABLE))
def test_a_huge_or_unreadable_answer_is_refused_unread_and_not_retried(
    name: str, server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    reply, expected = HUGE_OR_UNREADABLE[name]
    server.script(reply)
    started = time.perf_counter()
    with pytest.raises(KeympsError) as caught:
        run(hostile_task(tmp_path), tmp_path / "run", api_base=server.openai_base)
    assert_clean_error(caught.value)
    assert expected in str(caught.value) and "refused unread" in str(caught.value)
    assert time.perf_counter() - started < 5.0
    assert len(server.chat_requests) == 1 and RecordingExecutor.calls == []
    assert server.chat_requests[0].headers["accept-encoding"] == "gzip, deflate"
    fuzz_counter.add("VLM attacks/answer size", name, "refused unread")


@pytest.mark.parametrize("wbits", [16 + zlib.MAX_WBITS, zlib.MAX_WBITS, -zlib.MAX_WBITS])
def test_a_compressed_answer_of_a_normal_size_is_read(
    wbits: int, server: Any, tmp_path: Path
) -> None:
    coding = "gzip" if wbits > zlib.MAX_WBITS else "deflate"  # HTTP's deflate: zlib, or raw
    server.script(
        Reply.raw(_compressed(_completion(json.dumps(DOT)), wbits), {"Content-Encoding": coding})
    )
    run(hostile_task(tmp_path), tmp_path / "run", api_base=server.openai_base)
    assert len(RecordingExecutor.calls) == 1


def test_the_async_call_of_keymps_eval_has_the_same_cap(server: Any, gzip_bomb: bytes) -> None:
    from keymps.default_plugins.litellm.backend import LitellmBackend, LitellmOptions

    backend = LitellmBackend(
        LitellmOptions(model="openai/test-vlm", api_base=server.openai_base, timeout_s=30)
    )
    server.script(Reply.raw(gzip_bomb, {"Content-Encoding": "gzip"}))
    with pytest.raises(KeympsError, match="sent an answer larger than 8 MB: refused unread"):
        asyncio.run(backend.acomplete(plan_request(30)))
    assert len(server.chat_requests) == 1


def test_outside_keymps_calls_httpx_reads_as_its_own() -> None:
    """The cap holds only inside keymps' own calls: other code using httpx is unaffected."""
    import httpx

    from keymps.default_plugins.litellm.response_cap import answers_capped, install

    install()
    body = _compressed(bytes(9 * 2**20))
    request = httpx.Request("GET", "http://127.0.0.1/")
    plain = httpx.Response(200, headers={"Content-Encoding": "gzip"}, content=body, request=request)
    assert len(plain.read()) == 9 * 2**20
    with answers_capped(), pytest.raises(Exception, match="larger than 8 MB"):
        # (a Response given its content reads it at once)
        httpx.Response(200, headers={"Content-Encoding": "gzip"}, content=body, request=request)


def test_the_capped_inflater_gives_back_every_byte_however_the_body_is_chunked() -> None:
    """400 generated bodies (text-like, random, repetitive; 0-512 KB) in gzip, zlib and raw
    deflate, cut into random chunks: read inside the cap, each is its own bytes exactly."""
    import httpx

    from keymps.default_plugins.litellm.response_cap import answers_capped, install

    install()
    rng = np.random.default_rng(20261202)
    codings = {"gzip": 16 + zlib.MAX_WBITS, "deflate": zlib.MAX_WBITS, "raw deflate": -15}
    for case in range(400):
        kind = case % 3
        size = int(rng.integers(0, 2**19))
        if kind == 0:
            body = bytes(rng.integers(0, 256, size, dtype=np.uint8))
        elif kind == 1:
            body = bytes(rng.choice(np.frombuffer(b'{"pairs": [0, 1], }\n ', np.uint8), size))
        else:
            body = bytes(size)
        name = list(codings)[case % 3 if case % 5 else 0]
        packed = _compressed(body, codings[name])
        cuts = np.sort(rng.integers(0, len(packed) + 1, int(rng.integers(0, 30))))
        chunks = [packed[a:b] for a, b in zip([0, *cuts], [*cuts, len(packed)], strict=True)]
        request = httpx.Request("GET", "http://127.0.0.1/")
        header = "deflate" if name == "raw deflate" else name
        with answers_capped():
            response = httpx.Response(
                200, headers={"Content-Encoding": header}, stream=_chunks(chunks), request=request
            )
            assert response.read() == body, (case, name, size)


def _chunks(chunks: list[bytes]) -> Any:
    """An httpx stream giving these chunks, as a socket would."""
    import httpx

    class Chunks(httpx.SyncByteStream):
        def __iter__(self) -> Any:
            return iter(chunks)

    return Chunks()


def test_a_task_only_server_is_sent_no_image_from_outside_the_task_folder(
    server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    """A shared task could name any photo of yours (scene.image: /home/you/...) and a server of
    its own: the run sent no key, but still the photo's crop."""
    photo = tmp_path / "private" / "photo.png"
    photo.parent.mkdir()
    shutil.copy(REPO / "tasks/scenes/round_cake.png", photo)
    shared = tmp_path / "shared"
    linked = shared / "scenes" / "linked.png"
    for image in (str(photo), "../private/photo.png", "scenes/linked.png"):
        task = hostile_task(shared, f"api_base: {server.openai_base}")
        linked.parent.mkdir(exist_ok=True)
        if not linked.is_symlink():
            linked.symlink_to(photo)  # inside the folder by name, outside once followed
        task.write_text(task.read_text().replace("image: round_cake.png", f"image: {image}"))
        with pytest.raises(KeympsError) as caught:
            run(task, tmp_path / "run")
        assert_clean_error(caught.value)
        message = str(caught.value)
        assert message.startswith(f"{task}:") and f"scene.image {image} is outside" in message
        assert "sends none of your files to a server only a task file names" in message
        assert server.chat_requests == [] and RecordingExecutor.calls == []
        assert not (tmp_path / "run").exists()
        fuzz_counter.add("VLM attacks/trust", "task-only api_base, outside image", "refused")
    # the user's own choices are sent: --image, or the server by --api-base
    with pytest.warns(UserWarning, match="no API key is sent"):  # still the task's server
        run(task, tmp_path / "run-image", image=str(photo))
    assert len(server.chat_requests) == 1
    run(task, tmp_path / "run-api-base", api_base=server.openai_base)
    assert len(server.chat_requests) == 2 and len(RecordingExecutor.calls) == 2
