"""The `litellm` planner backend: any VLM litellm reaches (OpenAI, Anthropic, Gemini, Ollama, vLLM).

litellm is imported only when a request is made (it takes seconds), after
LITELLM_LOCAL_MODEL_COST_MAP=True so that the import never reaches for the network.
"""

from __future__ import annotations

import ipaddress
import os
import time
from typing import TYPE_CHECKING, Any
from urllib.parse import urlparse

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from keymps.errors import KeympsError
from keymps.hookspecs import hookimpl

if TYPE_CHECKING:
    from keymps.planning import BackendAnswer, PlanRequest

MAX_RETRIES = 3
"""Further tries after a rate limit (429) or a server error (5xx)."""
BACKOFF_S = 1.0
"""First wait between tries; doubled each time unless the server sends Retry-After."""
MAX_WAIT_S = 30.0

_LOCAL_PROVIDERS = {"ollama", "ollama_chat", "hosted_vllm", "lm_studio", "llamafile"}


class LitellmOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    model: str | None = None
    api_base: str | None = None
    api_key_env: str | None = None
    temperature: float = Field(default=0.0, ge=0, le=2)
    timeout_s: float = Field(default=60.0, gt=0)
    cassette: str | None = None
    retries: int = Field(default=MAX_RETRIES, ge=0, le=10)
    backoff_s: float = Field(default=BACKOFF_S, ge=0, le=60)


def import_litellm() -> Any:
    """litellm, imported quietly and without network access at import time."""
    os.environ.setdefault("LITELLM_LOCAL_MODEL_COST_MAP", "True")
    import litellm

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


def _retry_after(error: Exception) -> float | None:
    headers: Any = getattr(error, "litellm_response_headers", None)
    response = getattr(error, "response", None)
    if headers is None and response is not None:
        headers = getattr(response, "headers", None)
    if not headers:
        return None
    value = headers.get("retry-after") or headers.get("Retry-After")
    try:
        return float(value) if value is not None else None
    except ValueError:
        return None


class LitellmBackend:
    name = "litellm"
    cacheable = True

    def __init__(self, options: LitellmOptions):
        self.options = options
        self._registered: set[str] = set()

    def _api_key(self) -> str | None:
        env = self.options.api_key_env
        if env:
            value = os.environ.get(env)
            if not value:
                raise KeympsError(f"planner.api_key_env names ${env}, which is not set")
            return value
        return None

    def _register_local_model(self, litellm: Any, model: str) -> None:
        # litellm does not price local models; registering them at zero gives a cost of 0.0
        if model in self._registered:
            return
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
        self._registered.add(model)

    def complete(self, request: PlanRequest) -> BackendAnswer:
        from keymps.backend_choice import model_provider
        from keymps.planning import BackendAnswer

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
        if local:
            self._register_local_model(litellm, model)
        arguments: dict[str, Any] = {
            "model": model,
            "messages": request.messages,
            "temperature": self.options.temperature,
            "timeout": self.options.timeout_s,
            "num_retries": 0,
            "max_retries": 0,
            "drop_params": True,
        }
        if self.options.api_base:
            arguments["api_base"] = self.options.api_base
        key = self._api_key()
        if key is None and self.options.api_base and provider in ("openai", "hosted_vllm"):
            key = os.environ.get("OPENAI_API_KEY") if provider == "openai" else None
            key = key or "no-key-needed"  # OpenAI-compatible local servers want some key
        if key is not None:
            arguments["api_key"] = key
        if self._supports_schema(litellm, model, provider):
            arguments["response_format"] = {"type": "json_schema", "json_schema": request.schema}
        started = time.perf_counter()
        retries: list[str] = []
        response = self._call_with_retries(litellm, arguments, retries)
        latency = time.perf_counter() - started
        text = _answer_text(response)
        usage = getattr(response, "usage", None)
        cost: float | None
        try:
            cost = float(litellm.completion_cost(completion_response=response, model=model))
        except Exception:
            cost = 0.0 if local else None
        return BackendAnswer(
            text=text,
            prompt_tokens=getattr(usage, "prompt_tokens", None),
            completion_tokens=getattr(usage, "completion_tokens", None),
            latency_s=latency,
            cost_usd=cost,
            model=model,
            retries=tuple(retries),
        )

    @staticmethod
    def _supports_schema(litellm: Any, model: str, provider: str) -> bool:
        try:
            params = litellm.get_supported_openai_params(
                model=model.split("/", 1)[-1], custom_llm_provider=provider
            )
        except Exception:
            return False
        return bool(params) and "response_format" in params

    def _call_with_retries(
        self, litellm: Any, arguments: dict[str, Any], retries: list[str] | None = None
    ) -> Any:
        """litellm.completion, retried on rate limits and server errors (noted in `retries`)."""
        retryable = (
            litellm.RateLimitError,
            litellm.InternalServerError,
            litellm.ServiceUnavailableError,
            litellm.APIConnectionError,
            litellm.BadGatewayError,
        )
        wait = self.options.backoff_s
        where = self.options.api_base or arguments["model"]
        secrets = _secret_values(arguments)
        for attempt in range(self.options.retries + 1):
            try:
                return litellm.completion(**arguments)
            except litellm.Timeout:
                raise KeympsError(
                    f"the VLM ({arguments['model']} at {where}) gave no answer within "
                    f"{self.options.timeout_s:g} s (planner.timeout_s)"
                ) from None
            except litellm.AuthenticationError:
                raise KeympsError(
                    f"the VLM ({arguments['model']}) rejected the credentials; check the API key "
                    "environment variable (keys are never read from files)"
                ) from None
            except litellm.NotFoundError:
                raise KeympsError(
                    f"model {arguments['model']} not found at {where}; check planner.model"
                ) from None
            except retryable as error:
                if attempt == self.options.retries:
                    raise KeympsError(
                        f"the VLM ({arguments['model']} at {where}) failed after "
                        f"{attempt + 1} tries: {_short(error, secrets)}"
                    ) from None
                told = _retry_after(error)
                pause = min(told if told is not None else wait, MAX_WAIT_S)
                if retries is not None:
                    retries.append(
                        f"try {attempt + 1}: {_short(error, secrets)}; retried after {pause:g} s"
                    )
                time.sleep(pause)
                wait *= 2
            except litellm.BadRequestError as error:
                raise KeympsError(
                    f"the VLM ({arguments['model']}) refused the request: {_short(error, secrets)}"
                ) from None
            except litellm.APIError as error:
                raise KeympsError(
                    f"the VLM ({arguments['model']}) failed: {_short(error, secrets)}"
                ) from None
        raise AssertionError("unreachable")


def _secret_values(arguments: dict[str, Any]) -> list[str]:
    """The key sent and every credential-like variable: servers may quote them in errors."""
    names = [n for n in os.environ if n.endswith(("_API_KEY", "_TOKEN", "_SECRET"))]
    values = [str(arguments.get("api_key") or "")] + [os.environ[n] for n in names]
    return [v for v in values if len(v) >= 8 and v != "no-key-needed"]


def _short(error: Exception, secrets: list[str] | None = None) -> str:
    text = " ".join(str(error).split())
    for secret in secrets or ():
        text = text.replace(secret, "[redacted]")
    return text[:300] + ("..." if len(text) > 300 else "")


def _answer_text(response: Any) -> str:
    try:
        content = response.choices[0].message.content
    except (AttributeError, IndexError, TypeError):
        return ""
    if isinstance(content, list):  # some providers answer in parts
        return "".join(str(part.get("text", "")) for part in content if isinstance(part, dict))
    return content or ""


def _factory(options: dict[str, Any]) -> LitellmBackend:
    try:
        return LitellmBackend(LitellmOptions.model_validate(options))
    except ValidationError as error:
        first = error.errors(include_url=False)[0]
        field = ".".join(str(p) for p in first["loc"])
        raise KeympsError(f"litellm backend option {field}: {first['msg']}") from None


@hookimpl
def register_vlm_backends(register: Any) -> None:
    register("litellm", _factory)
