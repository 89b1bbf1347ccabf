"""Which planner backend a run uses: `auto` means a VLM when one is configured, else offline."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from keymps.config.trust import is_provider_endpoint, same_server
from keymps.config.user import config_path, load_user_config
from keymps.errors import KeympsError
from keymps.planning.redaction import redact_text, url_secrets

if TYPE_CHECKING:
    from keymps.config.task import Task

PROVIDER_KEYS: dict[str, tuple[str, ...]] = {
    "openai": ("OPENAI_API_KEY",),
    "anthropic": ("ANTHROPIC_API_KEY",),
    "gemini": ("GEMINI_API_KEY", "GOOGLE_API_KEY"),
    "vertex_ai": ("GOOGLE_APPLICATION_CREDENTIALS",),
    "azure": ("AZURE_API_KEY",),
    "mistral": ("MISTRAL_API_KEY",),
    "groq": ("GROQ_API_KEY",),
    "openrouter": ("OPENROUTER_API_KEY",),
    "together_ai": ("TOGETHERAI_API_KEY", "TOGETHER_API_KEY"),
    "xai": ("XAI_API_KEY",),
    "deepseek": ("DEEPSEEK_API_KEY",),
    "bedrock": ("AWS_ACCESS_KEY_ID",),
    "ollama": ("OLLAMA_API_BASE", "OLLAMA_API_KEY"),
    "ollama_chat": ("OLLAMA_API_BASE", "OLLAMA_API_KEY"),
    "llamafile": ("LLAMAFILE_API_BASE", "LLAMAFILE_API_KEY"),
    "lemonade": ("LEMONADE_API_BASE", "LEMONADE_API_KEY"),
    "docker_model_runner": ("DOCKER_MODEL_RUNNER_API_BASE", "DOCKER_MODEL_RUNNER_API_KEY"),
    "hosted_vllm": ("HOSTED_VLLM_API_BASE",),
}
"""litellm provider prefix -> environment variables that configure it (any one suffices)."""

LOCAL_DEFAULTS: dict[str, tuple[str, str]] = {
    "ollama": ("http://localhost:11434", "OLLAMA_API_BASE"),
    "ollama_chat": ("http://localhost:11434", "OLLAMA_API_BASE"),
    "llamafile": ("http://127.0.0.1:8080/v1", "LLAMAFILE_API_BASE"),
    "lemonade": ("http://localhost:8000/api/v1", "LEMONADE_API_BASE"),
    "docker_model_runner": (
        "http://localhost:22088/engines/llama.cpp",
        "DOCKER_MODEL_RUNNER_API_BASE",
    ),
}
"""Providers litellm sends to a port of this machine when no api_base is given: that address,
and the variable that names another. Any user of the machine may listen on a free port."""


AUTO_VLM = "litellm"
"""The backend `auto` chooses when a model is configured (any registered backend may be named)."""
AUTO_OFFLINE = "offline"
"""The backend `auto` chooses when none is."""
NO_SERVER = ("offline", "replay")
"""Built-in backends that call no server (no key can leave with their requests)."""
MODEL_FREE = (AUTO_OFFLINE,)
"""Backends that ask no model: --model or --api-base on the command line replaces them
(replay keeps answering from its cassette)."""


def model_provider(model: str) -> str:
    """The litellm provider of a model string ('openai/gpt-4o' -> 'openai', 'claude-...')."""
    if "/" in model:
        return model.split("/", 1)[0]
    if model.startswith("claude"):
        return "anthropic"
    if model.startswith("gemini"):
        return "gemini"
    return "openai"


def _key_variables(task: Task, model: str) -> tuple[str, ...]:
    """The environment variables that may configure `model`: the task's own, then its
    provider's (PROVIDER_KEYS)."""
    own = (task.planner.api_key_env,) if task.planner.api_key_env else ()
    return own + PROVIDER_KEYS.get(model_provider(model), ())


def credential_source(task: Task, model: str) -> str | None:
    """Which environment variable configures `model`, or None when none is set."""
    return next((name for name in _key_variables(task, model) if os.environ.get(name)), None)


def api_base_trusted(task: Task) -> bool:
    """May a backend send the user's key to the task's server? Yes when that is the provider's
    own endpoint (no api_base, or its https host), an api_base the user gave (--api-base,
    RunOverrides(api_base=...), a task built in code) or one listed in the user config; no when
    only the task file names it, and no for a provider's default address on this machine
    (`default_local_endpoint`) unless the user config lists it (docs/security.md)."""
    if not task.api_base_from_file:
        local = default_local_endpoint(task)
        return local is None or _listed(local)
    api_base = task.planner.api_base or ""
    if is_provider_endpoint(api_base, model_provider(task.planner.model or "")):
        return True
    return _listed(api_base)


def _listed(url: str) -> bool:
    return any(same_server(url, trusted) for trusted in load_user_config().trusted_api_bases)


def default_local_endpoint(task: Task) -> str | None:
    """The address on this machine litellm sends the task's model to when no server is named
    (Ollama's http://localhost:11434 ...: LOCAL_DEFAULTS); None when planner.api_base or the
    provider's own variable (OLLAMA_API_BASE ...) names one, or the provider has none."""
    if task.planner.api_base:
        return None
    default = LOCAL_DEFAULTS.get(model_provider(task.planner.model or ""))
    if default is None or os.environ.get(default[1]):
        return None
    return default[0]


def untrusted_server(task: Task) -> str:
    """The task's server the user did not name, in words: 'planner.api_base URL is named only
    by the task file', or the default local address only the task chose."""
    local = default_local_endpoint(task)
    if local is not None:
        return (
            f"planner.model {task.planner.model} is served at its provider's default address "
            f"{local}, which only the task file chose and any user of this machine may listen on"
        )
    return f"planner.api_base {task.planner.api_base} is named only by the task file"


def untrusted_api_base_warning(task: Task) -> str | None:
    """The one line a run prints when it sends no key because only the task chose the server
    (at a default local address: only when a key is there to withhold)."""
    if api_base_trusted(task):
        return None
    local = default_local_endpoint(task)
    if local is not None and not keys_the_task_may_send(task):
        return None
    field = "model" if local is not None else "api_base"
    lift = f"--api-base {local}" if local is not None else "--api-base"
    return redact_text(
        f"{task.where('planner', field)}: {untrusted_server(task)}, so no API key is sent to "
        f"it; to send one, pass {lift} or list it under trusted_api_bases in {config_path()}"
    )


def keys_the_task_may_send(task: Task) -> list[str]:
    """Every credential a backend may send for this task (for the redactor): the values of the
    key variables, and what planner.api_base carries (userinfo, ?api_key=)."""
    names = _key_variables(task, task.planner.model or "")
    keys = [name for name in names if not name.endswith("_API_BASE")]  # a URL, not a key
    values = [value for name in keys if (value := os.environ.get(name))]
    return values + url_secrets(task.planner.api_base)


def choose_backend(
    task: Task,
    backend_override: str | None,
    model_override: str | None,
    api_base_override: str | None,
) -> tuple[str, str]:
    """(backend name, one sentence saying why): `auto` means a VLM when one is configured."""
    model = model_override or task.planner.model
    api_base = api_base_override or task.planner.api_base
    requested, overridden = _requested(task, backend_override, model_override, api_base_override)
    if requested != "auto":
        _check_requested(task, requested, model, backend_override)
        origin = "--backend" if backend_override else "the task's planner.backend"
        return requested, f"{origin} asks for the {requested} planner"
    if not model:
        if overridden:
            raise KeympsError(
                f"--api-base {api_base}: no model to ask; pass --model too (e.g. "
                "openai/Qwen/Qwen2.5-VL-7B-Instruct)"
            )
        return (
            AUTO_OFFLINE,
            "no VLM model is configured (planner.model or --model): offline planner",
        )
    if api_base:
        return AUTO_VLM, f"model {model} is served at {api_base}{overridden}"
    source = credential_source(task, model)
    if source:
        return AUTO_VLM, f"model {model} with credentials from ${source}{overridden}"
    return _without_credentials(task, model, bool(model_override), overridden)


def _requested(
    task: Task,
    backend_override: str | None,
    model_override: str | None,
    api_base_override: str | None,
) -> tuple[str, str]:
    """(backend asked for, why the command line overrode the task's, or "")."""
    requested = backend_override or task.planner.backend
    if backend_override is not None or requested not in MODEL_FREE:
        return requested, ""
    if not (model_override or api_base_override):
        return requested, ""
    # a model or server given on the command line is meant, whatever the task file says
    given = " and ".join(
        flag
        for flag, value in (("--model", model_override), ("--api-base", api_base_override))
        if value
    )
    return "auto", f" ({given} on the command line overrides the task's backend: {requested})"


def _check_requested(
    task: Task, requested: str, model: str | None, backend_override: str | None
) -> None:
    """Refuse a named backend that cannot work, naming the flag or task line that asked."""
    try:
        _check_backend(task, requested, model)
    except KeympsError as error:
        if backend_override:
            raise KeympsError(f"--backend {requested}: {error}") from None
        raise KeympsError(f"{task.where('planner', 'backend')}: planner.backend: {error}") from None


def _without_credentials(
    task: Task, model: str, on_command_line: bool, overridden: str
) -> tuple[str, str]:
    """A model with no key and no server: offline, Ollama's default address, or refuse."""
    wanted = ((task.planner.api_key_env,) if task.planner.api_key_env else ()) + PROVIDER_KEYS.get(
        model_provider(model), ()
    )
    # "$OPENAI_API_KEY unset" for a provider keymps knows; else no key it could look for
    missing = (
        f"{' or '.join(f'${n}' for n in wanted)} unset, no api_base"
        if wanted
        else f"no key variable known for provider {model_provider(model)!r}, no api_base"
    )
    if on_command_line:
        # a model asked for on the command line is meant: never fall back silently
        if model_provider(model) in ("ollama", "ollama_chat"):
            return AUTO_VLM, f"model {model} from Ollama at its default address{overridden}"
        raise KeympsError(
            f"--model {model}: no credentials ({missing}); set the key's environment variable "
            "(planner.api_key_env names it), pass --api-base for a server of your own, or drop "
            "--model to plan offline"
        )
    return AUTO_OFFLINE, f"model {model} has no credentials ({missing}): offline planner"


def _check_backend(task: Task, backend: str, model: str | None) -> None:
    """Fail before any stage runs when the requested backend cannot work."""
    from keymps.plugin.manager import components

    available = components("vlm_backend")
    if backend not in available:
        choices = ", ".join(["auto", *sorted(available)])
        raise KeympsError(f"unknown planner backend {backend!r} (available: {choices})")
    if backend == AUTO_VLM and not model:
        raise KeympsError(
            "the litellm backend needs a model: set planner.model or pass --model "
            "(e.g. openai/gpt-4o; see docs/vlm.md)"
        )
    if backend == "replay" and task.planner.cassette is None:
        raise KeympsError(
            "the replay backend needs a cassette: set planner.cassette or pass --cassette FILE.jsonl"
        )
