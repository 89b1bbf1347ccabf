"""A task that names a local provider and no server sends no key to its default port.

`ollama/`, `ollama_chat/`, `llamafile/`, `lemonade/` and `docker_model_runner/` models go to a
fixed port of this machine when no api_base is given (11434, 8080, 8000, 22088), where any
user of the machine may listen. A shared task naming such a
model and `api_key_env: OPENAI_API_KEY` (or STRIPE_API_KEY, or nothing: litellm reads
OLLAMA_API_KEY ... itself) sent that key in clear text to whoever listened. Each case runs
`keymps run` against a real listener on the provider's default port of 127.0.0.1 (skipped,
saying so, where another program holds the port): the run works keyless and says so once, and
the key reaches the port only when the user names the address (--api-base, the provider's
*_API_BASE variable, trusted_api_bases).
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
from pathlib import Path
from typing import Any

import pytest
from helpers.fuzz_support import REPO, RecordingExecutor, install
from helpers.vlm_server import VlmServer

import keymps
from keymps.bundled import bundled_dir
from keymps.errors import KeympsError
from keymps.run import RunOptions, RunOverrides

DOT = {"keyword": "line", "pairs": [[[130, 130], [130, 130]]], "rationale": "one dot"}
KEY = "sk-canary-" + secrets.token_hex(12)
LOCAL_DEFAULTS = {
    "ollama": ("http://localhost:11434", "OLLAMA_API_BASE"),
    "ollama_chat": ("http://localhost:11434", "OLLAMA_API_BASE"),
    "llamafile": ("http://127.0.0.1:8080/v1", "LLAMAFILE_API_BASE"),
    "lemonade": ("http://localhost:8000/api/v1", "LEMONADE_API_BASE"),
    "docker_model_runner": (
        "http://localhost:22088/engines/llama.cpp",
        "DOCKER_MODEL_RUNNER_API_BASE",
    ),
}
"""Where litellm sends each provider's requests when no server is named, and the variable
that names another (litellm's own defaults, read from its source)."""
PROVIDERS = sorted(LOCAL_DEFAULTS)
OWN_KEY = {
    "ollama": "OLLAMA_API_KEY",
    "ollama_chat": "OLLAMA_API_KEY",
    "llamafile": "LLAMAFILE_API_KEY",
    "lemonade": "LEMONADE_API_KEY",
    "docker_model_runner": "DOCKER_MODEL_RUNNER_API_KEY",
}
"""The variable litellm itself reads for each provider when it is given no key."""


@pytest.fixture(scope="module", autouse=True)
def _litellm() -> None:
    from keymps.default_plugins.litellm.backend import import_litellm

    import_litellm()  # seconds, once


@pytest.fixture(autouse=True)
def _isolated(keymps_plugins: Any, monkeypatch: Any, tmp_path: Path) -> None:
    install(keymps_plugins)
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("KEYMPS_CONFIG", str(tmp_path / "user-config.yaml"))
    for _address, variable in LOCAL_DEFAULTS.values():
        monkeypatch.delenv(variable, raising=False)
    for variable in OWN_KEY.values():
        monkeypatch.delenv(variable, raising=False)


_LISTENERS: dict[int, VlmServer | str] = {}
"""One listener per default port for the whole module (litellm keeps its connections open:
a new server on the same port would not see requests sent over an old one), or why not."""


@pytest.fixture(scope="module", autouse=True)
def _listeners_closed() -> Any:
    yield
    for server in _LISTENERS.values():
        if isinstance(server, VlmServer):
            server.close()
    _LISTENERS.clear()


def listener(provider: str) -> VlmServer:
    """The VLM server on the provider's default port of 127.0.0.1 (its records cleared), or a
    skip naming the port when another program holds it."""
    port = int(LOCAL_DEFAULTS[provider][0].split(":")[2].split("/")[0])
    if port not in _LISTENERS:
        try:
            server = VlmServer(responder=lambda request: json.dumps(DOT), port=port)
            _LISTENERS[port] = server.__enter__()
        except OSError as error:
            _LISTENERS[port] = f"{provider}'s default port {port} is in use here ({error.strerror})"
    found = _LISTENERS[port]
    if isinstance(found, str):
        pytest.skip(found)
    found.reset()
    return found


def local_task(folder: Path, provider: str, key_env: str | None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    text = (REPO / "tasks" / "cake_icing.yaml").read_text()
    # a new model name each time: litellm looks a model up (with its own key variable) once
    planner = f"model: {provider}/llava-{secrets.token_hex(4)}\n  cache: false"
    if key_env:
        planner += f"\n  api_key_env: {key_env}"
    text = text.replace("model: openai/gpt-4o", planner).replace("Put 15 icing dots", "Put 1")
    text = text.replace("backend: auto", "backend: litellm")
    text = text.replace("../prompts/", f"{bundled_dir('prompts')}/")  # the user's
    if not (folder / "scenes").exists():  # the scene inside the task's folder
        shutil.copytree(REPO / "tasks" / "scenes", folder / "scenes")
    (folder / "task.yaml").write_text(text)
    return folder / "task.yaml"


def run(task: Path, out: Path, **given: Any) -> Any:
    options = {k: given.pop(k) for k in ("record", "no_cache") if k in given}
    return keymps.run_task(
        task,
        options=RunOptions(rerun="off", **options),
        overrides=RunOverrides(executor="recording", out=out, **given),
    )


def heard_key(server: VlmServer) -> bool:
    return any(KEY in json.dumps([r.headers, r.body]) for r in server.requests)


@pytest.mark.parametrize("key_env", ["OPENAI_API_KEY", "STRIPE_API_KEY", "own"])
@pytest.mark.parametrize("provider", PROVIDERS)
def test_no_key_goes_to_a_default_local_port_only_the_task_chose(
    provider: str, key_env: str, tmp_path: Path, monkeypatch: Any, fuzz_counter: Any
) -> None:
    variable = OWN_KEY[provider] if key_env == "own" else key_env
    monkeypatch.setenv(variable, KEY)
    task = local_task(tmp_path / "task", provider, None if key_env == "own" else key_env)
    server = listener(provider)
    with pytest.warns(UserWarning) as warned:
        finished = run(task, tmp_path / "run")
    assert server.chat_requests, "the keyless run still asks the local server"
    assert not heard_key(server)
    notes = [str(w.message) for w in warned if "no API key is sent" in str(w.message)]
    assert len(notes) == 1 and LOCAL_DEFAULTS[provider][0] in notes[0], notes
    assert f"--api-base {LOCAL_DEFAULTS[provider][0]}" in notes[0]
    assert len(RecordingExecutor.calls) == 1
    record = json.loads((finished.folder / "run.json").read_text())
    assert sum("no API key is sent" in w for w in record["warnings"]) == 1
    fuzz_counter.add("VLM attacks/local ports", (provider, key_env), "keyless run")


@pytest.mark.parametrize("named_by", ["--api-base", "variable", "trusted_api_bases"])
@pytest.mark.parametrize("provider", ["ollama", "llamafile"])
def test_the_default_address_the_user_names_gets_the_key(
    provider: str, named_by: str, tmp_path: Path, monkeypatch: Any, fuzz_counter: Any
) -> None:
    address, variable = LOCAL_DEFAULTS[provider]
    monkeypatch.setenv("LAB_VLM_API_KEY", KEY)
    task = local_task(tmp_path / "task", provider, "LAB_VLM_API_KEY")
    overrides = {"api_base": address} if named_by == "--api-base" else {}
    if named_by == "variable":
        monkeypatch.setenv(variable, address)
    if named_by == "trusted_api_bases":
        (tmp_path / "user-config.yaml").write_text(f"trusted_api_bases: ['{address}']\n")
    server = listener(provider)
    run(task, tmp_path / "run", **overrides)
    assert heard_key(server)
    fuzz_counter.add("VLM attacks/local ports", (provider, named_by), "key sent")


def test_a_task_without_a_key_to_withhold_runs_without_a_warning(
    tmp_path: Path, recwarn: Any
) -> None:
    """Keyless Ollama is the common case: nothing to warn about."""
    server = listener("ollama")
    run(local_task(tmp_path / "task", "ollama", None), tmp_path / "run")
    assert server.chat_requests and not heard_key(server)
    assert not [w for w in recwarn if "API key" in str(w.message)]


def test_a_default_local_port_is_sent_no_hard_linked_file(tmp_path: Path) -> None:
    """Like any server the user did not name: no file that may be one of theirs."""
    task = local_task(tmp_path / "task", "ollama", None)
    os.link(REPO / "tasks/scenes/round_cake.png", tmp_path / "task" / "scene.png")
    task.write_text(task.read_text().replace("scenes/round_cake.png", "scene.png"))
    with pytest.raises(KeympsError, match="is a hard link") as caught:
        run(task, tmp_path / "run")
    assert "default address http://localhost:11434" in str(caught.value)
    assert RecordingExecutor.calls == []


def test_a_task_only_api_base_keeps_litellms_own_lookups_keyless_too(
    tmp_path: Path, monkeypatch: Any, fuzz_counter: Any
) -> None:
    """litellm looks an Ollama model up at its default address with $OLLAMA_API_KEY, whatever
    api_base the call has: with a server only the task names, that request is not sent."""
    default = listener("ollama")
    monkeypatch.setenv("OLLAMA_API_KEY", KEY)
    with VlmServer(responder=lambda request: json.dumps(DOT)) as elsewhere:
        task = local_task(tmp_path / "task", "ollama", None)
        task.write_text(
            task.read_text().replace("cache: false", f"cache: false\n  api_base: {elsewhere.url}")
        )
        with pytest.warns(UserWarning, match="no API key is sent"):
            run(task, tmp_path / "run")
        assert elsewhere.chat_requests and not heard_key(elsewhere)
    assert not heard_key(default)
    fuzz_counter.add("VLM attacks/local ports", "task-only api_base, lookup", "no key")
