"""When and how long to retry a failed VLM call (shared by litellm's blocking and async calls).

Rate limits (429), server errors (5xx) and lost connections are retried a bounded number of
times: after the server's Retry-After (seconds, milliseconds or an HTTP date) when it sends one,
else after an exponential backoff with jitter, so that many runs told to wait do not all come
back at the same instant. A refused connection is retried once, quickly (nobody is listening:
waiting seconds will not change that); missing credentials and an HTML page are not retried.
Every other failure, and the last retryable one, becomes one line saying what happened.
"""

from __future__ import annotations

import email.utils
import random
import time
from dataclasses import dataclass, field
from typing import Any

from keymps.default_plugins.litellm.failures import classify, redirected
from keymps.errors import KeympsError
from keymps.planning.redaction import Form, known_secrets, redact_text, remember

MAX_WAIT_S = 30.0
"""No single wait is longer, whatever the server asks."""
JITTER = 0.5
"""A backoff wait is stretched by a random fraction of itself, up to this much."""
REFUSED_RETRIES = 1
"""Further tries after a refused connection (a local server that is just starting)."""
REFUSED_WAIT_S = 0.5
"""The wait before that one retry."""


def retry_after_s(error: Exception, now: float | None = None) -> float | None:
    """The wait the server asked for (Retry-After, retry-after-ms), if it asked."""
    headers: Any = getattr(error, "litellm_response_headers", None)
    response = getattr(error, "response", None)
    if not headers and response is not None:
        headers = getattr(response, "headers", None)
    if not headers:
        return None
    milliseconds = headers.get("retry-after-ms")
    try:
        if milliseconds is not None:
            return max(0.0, float(milliseconds) / 1000)
    except ValueError:
        pass
    value = headers.get("retry-after") or headers.get("Retry-After")
    if value is None:
        return None
    try:
        return max(0.0, float(value))
    except ValueError:
        pass
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError):
        return None
    return max(0.0, when.timestamp() - (time.time() if now is None else now))


def secret_values(arguments: dict[str, Any]) -> list[Form]:
    """Every secret to blank in messages (servers may quote keys in errors): the key sent, which
    the shared redactor then remembers, and every credential-like variable."""
    remember(arguments.get("api_key"))
    return known_secrets()


def short(error: Exception, secrets: list[Form] | None = None) -> str:
    """The error as one line of at most 300 characters, secrets blanked out."""
    text = redact_text(" ".join(str(error).split()), secrets)
    return text[:300] + ("..." if len(text) > 300 else "")


@dataclass
class Retrying:
    """The retry state of one call: what to do after each failed try."""

    litellm: Any
    arguments: dict[str, Any]
    retries: int
    backoff_s: float
    timeout_s: float
    where: str | None
    """The api_base the user gave, if any (the provider's own endpoint otherwise)."""
    notes: list[str] = field(default_factory=list)
    """One line per failed try that was retried (the run's vlm/ records show them)."""

    def __post_init__(self) -> None:
        self.secrets = secret_values(self.arguments)
        self.wait = self.backoff_s

    def label(self) -> str:
        model = self.arguments["model"]
        return f"the VLM ({model} at {self.where})" if self.where else f"the VLM ({model})"

    def pause_after(self, error: Exception, attempt: int) -> float | None:
        """Seconds to wait before the next try; None for an error that is not litellm's; a
        KeympsError (one line) when the call has failed for good."""
        litellm, model = self.litellm, self.arguments["model"]
        moved = redirected(error)  # whatever the target then said (404, 405 ...), this is why
        if moved is not None:
            raise KeympsError(f"{self.label()}: {moved.text}")
        if isinstance(error, litellm.Timeout):
            raise KeympsError(
                f"{self.label()} gave no answer within {self.timeout_s:g} s (planner.timeout_s)"
            )
        if isinstance(error, litellm.AuthenticationError):
            raise KeympsError(
                f"the VLM ({model}) rejected the credentials; check the API key environment "
                "variable (keys are never read from files)"
            )
        if isinstance(error, litellm.NotFoundError):
            at = f" at {self.where}" if self.where else ""
            raise KeympsError(f"model {model} not found{at}; check planner.model")
        retryable = (
            litellm.RateLimitError,
            litellm.InternalServerError,
            litellm.ServiceUnavailableError,
            litellm.APIConnectionError,
            litellm.BadGatewayError,
        )
        if not isinstance(error, (*retryable, litellm.BadRequestError, litellm.APIError)):
            return None
        failure = classify(error, self.where)
        what = failure.text if failure else short(error, self.secrets)
        tries = f"{attempt + 1} tries" if attempt else "1 try"
        if failure is not None and failure.retry == "no":
            raise KeympsError(f"{self.label()}: {what}")
        if failure is not None and failure.retry == "briefly":
            if attempt >= min(self.retries, REFUSED_RETRIES):
                raise KeympsError(f"{self.label()}: {what} after {tries}; is the server running?")
            return self._note(attempt, what, REFUSED_WAIT_S)
        if isinstance(error, retryable):
            if attempt >= self.retries:
                status = getattr(error, "status_code", None)
                # litellm says 500 for failures that never got an HTTP answer: name real ones only
                real = failure is None and isinstance(status, int)
                last = f" (the last one: HTTP {status})" if real else ""
                raise KeympsError(f"{self.label()} failed after {tries}{last}: {what}")
            told = retry_after_s(error)
            pause = told if told is not None else self.wait * (1 + JITTER * random.random())
            self.wait *= 2
            return self._note(attempt, what, min(pause, MAX_WAIT_S))
        if isinstance(error, litellm.BadRequestError):
            raise KeympsError(f"{self.label()} refused the request: {what}")
        raise KeympsError(f"{self.label()} failed: {what}")

    def _note(self, attempt: int, what: str, pause: float) -> float:
        self.notes.append(f"try {attempt + 1}: {what}; retried after {pause:.3g} s")
        return pause
