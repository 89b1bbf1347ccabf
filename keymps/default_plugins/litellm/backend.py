"""The `litellm` planner backend: any VLM litellm reaches (OpenAI, Anthropic, Gemini, Ollama, vLLM).

litellm is imported only when a request is made (it takes seconds), after
LITELLM_LOCAL_MODEL_COST_MAP=True so that the import never reaches for the network.
"""

from __future__ import annotations

import functools
import ipaddress
import os
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any
from urllib.parse import urlparse

from pydantic import BaseModel, ConfigDict, Field

from keymps.default_plugins.litellm.deadline import DeadlineExceeded, await_within, call_within
from keymps.default_plugins.litellm.retry import Retrying
from keymps.errors import KeympsError
from keymps.planning.redaction import remember, url_secrets
from keymps.plugin import BackendBase, parse_options

if TYPE_CHECKING:
    from keymps.types import BackendAnswer, PlanRequest

MAX_RETRIES = 3
"""Further tries after a rate limit (429) or a server error (5xx)."""
BACKOFF_S = 1.0
"""First wait between tries; doubled each time (plus jitter) unless the server sends Retry-After."""

_SETTING_UP = threading.RLock()
"""Held while litellm is imported (a run's plan stage waits here for the import that `prepare`
started on another thread), and while a local model is registered."""
_REGISTERED: set[str] = set()
"""Local models registered with litellm at zero price in this process."""
_LOCAL_PROVIDERS = {"ollama", "ollama_chat", "hosted_vllm", "lm_studio", "llamafile"}
_ENVIRONMENT_SIGNED = (
    "bedrock",
    "sagemaker",
    "vertex_ai",
    "oci",
    "snowflake",
    "watsonx",
    "github_copilot",
)
"""Providers (and every provider whose name starts with one: sagemaker_chat, sagemaker_nova,
vertex_ai_beta, watsonx_text ...) whose requests litellm signs or authorizes with credentials
it finds itself (cloud SDK credentials, key files, tokens from the environment), whatever key
keymps gives it."""


class LitellmOptions(BaseModel):
    model_config = ConfigDict(defer_build=True, extra="forbid")
    model: str | None = None
    api_base: str | None = None
    api_key_env: str | None = None
    temperature: float = Field(default=0.0, ge=0, le=2)
    timeout_s: float = Field(default=60.0, gt=0)
    max_tokens: int | None = Field(default=None, ge=1)
    cassette: str | None = None
    retries: int = Field(default=MAX_RETRIES, ge=0, le=10)
    backoff_s: float = Field(default=BACKOFF_S, ge=0, le=60)
    api_base_trusted: bool = False
    """False when only the task file chose the server (its api_base, or the provider's default
    port on this machine): no key from the environment is sent."""


def import_litellm() -> Any:
    """litellm, imported quietly and without network access at import time (from any thread:
    a second caller waits for the first one's import)."""
    with _SETTING_UP:
        os.environ.setdefault("LITELLM_LOCAL_MODEL_COST_MAP", "True")
        import litellm

        from keymps.default_plugins.litellm import closing, request_guard, response_cap

        response_cap.install()
        request_guard.install()
        closing.install()
        litellm.suppress_debug_info = True
        litellm.telemetry = False
        return litellm


def is_local(api_base: str | None, provider: str) -> bool:
    """True for models served on this machine (their calls cost nothing)."""
    if provider in _LOCAL_PROVIDERS and not api_base:
        return True
    if not api_base:
        return False
    host = urlparse(api_base).hostname or ""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class LitellmBackend(BackendBase):
    name = "litellm"
    cacheable = True
    supports_async = True

    def __init__(self, options: LitellmOptions):
        self.options = options

    def prepare(self) -> None:
        """Import litellm and set up its first call now: keymps calls this on a thread as soon
        as a run knows it plans with litellm (it then overlaps the stages before planning),
        and once in the warm planner (keymps.default_plugins.litellm.warm_up)."""
        from keymps.default_plugins.litellm import warm_up as first_call

        warm = LitellmBackend(
            LitellmOptions(model=first_call.WARM_UP_MODEL, api_base=first_call.WARM_UP_API_BASE)
        )
        first_call.warm_up(import_litellm(), warm)

    def _api_key(self) -> str | None:
        env = self.options.api_key_env
        if env:
            value = os.environ.get(env)
            if not value:
                raise KeympsError(f"planner.api_key_env names ${env}, which is not set")
            return value
        return None

    def _key_for(self, provider: str) -> str | None:
        """The key this call sends: none from the environment to an api_base that only a task
        file names, or to a default local port (docs/security.md); else planner.api_key_env
        or the provider's variable."""
        from keymps.planning.backend_choice import PROVIDER_KEYS

        api_base = self.options.api_base
        if not self._server_trusted(provider):
            if provider.startswith(_ENVIRONMENT_SIGNED):
                raise KeympsError(
                    f"planner.api_base {api_base} is named only by the task file, and {provider} "
                    "signs every request with your cloud credentials: pass --api-base, or list it "
                    "under trusted_api_bases in your user config (docs/security.md)"
                )
            return "no-key-needed"  # given, so that litellm reads no key variable itself
        key = self._api_key()
        if key is None:  # read here, not by litellm, so that the key sent is known
            names = [n for n in PROVIDER_KEYS.get(provider, ()) if n.endswith("_API_KEY")]
            key = next((os.environ[n] for n in names if os.environ.get(n)), None)
        if key is None and api_base and provider in ("openai", "hosted_vllm"):
            key = "no-key-needed"  # OpenAI-compatible local servers want some key
        return key

    def _server_trusted(self, provider: str) -> bool:
        """Whether the call's server is the user's: not an api_base only the task file names,
        nor a provider's default address on this machine only the task chose."""
        from keymps.planning.backend_choice import LOCAL_DEFAULTS

        chosen = bool(self.options.api_base) or provider in LOCAL_DEFAULTS
        return self.options.api_base_trusted or not chosen

    def _register_local_model(self, litellm: Any, model: str) -> None:
        # litellm does not price local models; registering them at zero gives a cost of 0.0
        if model in _REGISTERED:  # once per process: every call of an eval builds a backend
            return
        with _SETTING_UP:  # one at a time: each quiets litellm's logger and restores it
            self._register_now(litellm, model)

    @staticmethod
    def _register_now(litellm: Any, model: str) -> None:
        import logging

        provider = model.split("/", 1)[0] if "/" in model else "openai"
        logger = logging.getLogger("LiteLLM")
        level = logger.level
        logger.setLevel(logging.ERROR)  # it warns that a custom model has no cache pricing
        try:
            litellm.register_model(
                {
                    model: {
                        "input_cost_per_token": 0.0,
                        "output_cost_per_token": 0.0,
                        "litellm_provider": provider,
                        "mode": "chat",
                        "supports_vision": True,
                        "supports_response_schema": True,
                    }
                }
            )
        except Exception:  # pricing is a nicety; never fail a call over it
            return
        finally:
            logger.setLevel(level)
        _REGISTERED.add(model)

    def complete(self, request: PlanRequest) -> BackendAnswer:
        call = self.prepare_call(request)
        started = time.perf_counter()
        retrying = self._retrying(call)
        for attempt in range(self.options.retries + 1):
            try:
                response = self._within_deadline(call)
                break
            except Exception as error:
                pause = retrying.pause_after(error, attempt)
                if pause is None:
                    raise
                time.sleep(pause)
        return self.answer_from_response(
            call, response, time.perf_counter() - started, retrying.notes
        )

    async def acomplete(self, request: PlanRequest) -> BackendAnswer:
        """complete() through litellm's async API: waits and retries without blocking a thread."""
        import asyncio

        call = self.prepare_call(request)
        started = time.perf_counter()
        retrying = self._retrying(call)
        for attempt in range(self.options.retries + 1):
            try:
                response = await self._awaited_within_deadline(call)
                break
            except Exception as error:
                pause = retrying.pause_after(error, attempt)
                if pause is None:
                    raise
                await asyncio.sleep(pause)
        return self.answer_from_response(
            call, response, time.perf_counter() - started, retrying.notes
        )

    def _within_deadline(self, call: PreparedCall) -> Any:
        """One try, ended by planner.timeout_s whatever the server does (deadline.py)."""
        from keymps.default_plugins.litellm.request_guard import guarded
        from keymps.default_plugins.litellm.response_cap import answers_capped

        def capped() -> Any:
            with answers_capped(), guarded(call.server_trusted):  # in the thread that sends
                return call.litellm.completion(**call.arguments)

        try:
            return call_within(self.options.timeout_s, capped)
        except DeadlineExceeded:
            raise _timeout(call) from None

    async def _awaited_within_deadline(self, call: PreparedCall) -> Any:
        from keymps.default_plugins.litellm.request_guard import guarded
        from keymps.default_plugins.litellm.response_cap import answers_capped

        async def capped() -> Any:
            with answers_capped(), guarded(call.server_trusted):
                return await call.litellm.acompletion(**call.arguments)

        try:
            return await await_within(self.options.timeout_s, capped())
        except DeadlineExceeded:
            raise _timeout(call) from None

    def prepare_call(self, request: PlanRequest) -> PreparedCall:
        """The litellm arguments for `request`: model, messages, key, server and schema."""
        from keymps.default_plugins.litellm.request_guard import guarded
        from keymps.planning.backend_choice import model_provider

        model = request.model or self.options.model
        if not model:
            raise KeympsError(
                "the litellm backend needs a model: set planner.model or pass --model "
                "(e.g. openai/gpt-4o, anthropic/claude-sonnet-4-5, gemini/gemini-2.0-flash, "
                "ollama/llava)"
            )
        litellm = import_litellm()
        provider = model_provider(model)
        local = is_local(self.options.api_base, provider)
        trusted = self._server_trusted(provider)
        if local:
            with guarded(trusted):  # litellm looks the model up on the server
                self._register_local_model(litellm, model)
        arguments: dict[str, Any] = {
            "model": model,
            "messages": request.messages,
            "temperature": self.options.temperature,
            "timeout": self.options.timeout_s,
            "num_retries": 0,
            "max_retries": 0,
            "drop_params": True,
            # what response_cap inflates (httpx would also offer br and zstd where installed)
            "extra_headers": {"Accept-Encoding": "gzip, deflate"},
        }
        if self.options.max_tokens is not None:
            arguments["max_tokens"] = self.options.max_tokens
        if self.options.api_base:
            arguments["api_base"] = self.options.api_base
        key = self._key_for(provider)
        # redacted from everything written or printed, whatever its length
        remember(key, *url_secrets(self.options.api_base))
        if key is not None:
            arguments["api_key"] = key
        with guarded(trusted):
            if _supports_schema(litellm, model, provider):
                schema = {"type": "json_schema", "json_schema": request.schema}
                arguments["response_format"] = schema
        return PreparedCall(litellm, model, local, arguments, trusted)

    def _retrying(self, call: PreparedCall) -> Retrying:
        return Retrying(
            call.litellm,
            call.arguments,
            retries=self.options.retries,
            backoff_s=self.options.backoff_s,
            timeout_s=self.options.timeout_s,
            where=self.options.api_base,
        )

    @staticmethod
    def answer_from_response(
        call: PreparedCall, response: Any, latency: float, notes: list[str]
    ) -> BackendAnswer:
        """litellm's `response` to `call` as keymps' answer: text, usage, cost, `latency` (s)."""
        from keymps.types import BackendAnswer

        usage = getattr(response, "usage", None)
        # litellm prices every response it returns; ask again only when it could not
        cost: Any = (getattr(response, "_hidden_params", None) or {}).get("response_cost")
        if cost is None:
            from keymps.default_plugins.litellm.request_guard import guarded

            try:
                with guarded(call.server_trusted):  # pricing may look the model up
                    cost = call.litellm.completion_cost(
                        completion_response=response, model=call.model
                    )
            except Exception:
                cost = None
        if cost is None and call.local:
            cost = 0.0
        finish_reason, refusal = _how_it_ended(response)
        return BackendAnswer(
            text=_answer_text(response),
            finish_reason=finish_reason,
            refusal=refusal,
            prompt_tokens=getattr(usage, "prompt_tokens", None),
            completion_tokens=getattr(usage, "completion_tokens", None),
            latency_s=latency,
            cost_usd=float(cost) if cost is not None else None,
            model=call.model,
            retries=tuple(notes),
        )


def _timeout(call: PreparedCall) -> Exception:
    """litellm's own Timeout, so that the deadline reads like every other timeout."""
    provider = call.model.split("/", 1)[0] if "/" in call.model else "openai"
    return call.litellm.Timeout(message="deadline", model=call.model, llm_provider=provider)


@dataclass(frozen=True)
class PreparedCall:
    """One prepared call: litellm, the model, whether it runs locally, the arguments, and
    whether its server is the user's (keymps.default_plugins.litellm.request_guard)."""

    litellm: Any
    model: str
    local: bool
    arguments: dict[str, Any]
    server_trusted: bool


@functools.lru_cache(maxsize=64)
def _supports_schema(litellm: Any, model: str, provider: str) -> bool:
    try:
        params = litellm.get_supported_openai_params(
            model=model.split("/", 1)[-1], custom_llm_provider=provider
        )
    except Exception:
        return False
    return bool(params) and "response_format" in params


def _answer_text(response: Any) -> str:
    try:
        content = response.choices[0].message.content
    except (AttributeError, IndexError, TypeError):
        return ""
    if isinstance(content, list):  # some providers answer in parts
        return "".join(str(part.get("text", "")) for part in content if isinstance(part, dict))
    return content or ""


_EARLY_ENDS = {"length", "content_filter", "tool_calls", "function_call"}
"""finish_reason values that end an answer before the model meant to (OpenAI's, which litellm
maps every provider's to)."""


def _how_it_ended(response: Any) -> tuple[str | None, str | None]:
    """(finish_reason when the answer ended early, the model's refusal message if it refused)."""
    try:
        choice = response.choices[0]
    except (AttributeError, IndexError, TypeError):
        return None, None
    reason = getattr(choice, "finish_reason", None)
    message = getattr(choice, "message", None)
    if getattr(message, "tool_calls", None) or getattr(message, "function_call", None):
        reason = "tool_calls"  # some servers call a tool and still say "stop"
    refusal = getattr(message, "refusal", None)
    return (
        str(reason) if reason in _EARLY_ENDS else None,
        str(refusal)[:500] if isinstance(refusal, str) and refusal.strip() else None,
    )


def make_backend(options: dict[str, Any]) -> LitellmBackend:
    """The backend for a task's planner options (registered by keymps.default_plugins.litellm)."""
    return LitellmBackend(parse_options(LitellmOptions, options, "litellm backend"))
