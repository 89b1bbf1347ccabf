"""What keymps' own VLM requests may do on the wire, whatever litellm's HTTP clients do.

litellm builds its own clients per provider (the OpenAI SDK's, its handlers for Anthropic,
Gemini ..., httpx over aiohttp for keymps eval) and makes side requests of its own. Two rules
hold for every request made inside `guarded()` (a context variable: only keymps' own calls,
only in the thread or task that makes them):

- no redirect to another scheme, host or port is followed (RedirectRefused): httpx drops only
  `Authorization` on the way, so Anthropic's `x-api-key`, Gemini's `x-goog-api-key`, the image
  and the prompt went along to whatever a 302 or 307 named;
- a request to a server the user did not name carries the value of no credential-like
  environment variable (SecretRefused): litellm reads some key variables itself, whatever key
  keymps gives it (Ollama's model lookup sends `OLLAMA_API_KEY` to `localhost:11434`,
  Lemonade's `LEMONADE_API_KEY` to `localhost:8000`); its side requests fall back quietly when
  refused.

`install()` wraps httpx.Client's and httpx.AsyncClient's `send` and `_build_redirect_request`
once per process; outside keymps' calls httpx behaves as its own.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

MAX_SCANNED_BODY = 16 * 2**20
"""A request body this large or larger is not searched for secrets (a plan request with its
image is well under 1 MB)."""


@dataclass(frozen=True)
class _Rules:
    server_trusted: bool
    """False: the server is one only the task chose, which no secret may reach."""


_rules: contextvars.ContextVar[_Rules | None] = contextvars.ContextVar(
    "keymps_request_guard", default=None
)
_installed = False


class RedirectRefused(Exception):
    """A server redirected a VLM request to another origin; it was not followed."""

    def __init__(self, status: int, source: str, target: str):
        self.status = status
        """The redirect's HTTP status (301, 302, 303, 307, 308)."""
        self.source = source
        """The URL that redirected."""
        self.target = target
        """Where it redirected to (not contacted)."""
        super().__init__(f"HTTP {status} from {source} to {target} not followed")


class SecretRefused(Exception):
    """A request to a server the user did not name would have carried a secret; not sent."""

    def __init__(self, what: str, url: str):
        self.what = what
        """Which secret, by its variable's name ('$OLLAMA_API_KEY'), never by its value."""
        self.url = url
        """Where the request was going (not contacted)."""
        super().__init__(f"a request to {url} would have carried {what}; not sent")


@contextlib.contextmanager
def guarded(server_trusted: bool) -> Iterator[None]:
    """Within this block (this thread, this task), keymps' request rules hold."""
    token = _rules.set(_Rules(server_trusted))
    try:
        yield
    finally:
        _rules.reset(token)


def install() -> None:
    """Wrap httpx's send and redirect steps once per process (no-ops outside `guarded`)."""
    global _installed
    if _installed:
        return
    import httpx

    for client in (httpx.Client, httpx.AsyncClient):
        redirect = _no_redirect_elsewhere(client._build_redirect_request)
        client._build_redirect_request = redirect  # type: ignore[method-assign]
    own_send, own_asend = httpx.Client.send, httpx.AsyncClient.send

    def send(self: httpx.Client, request: httpx.Request, **kwargs: Any) -> httpx.Response:
        _check_secrets(request)
        return own_send(self, request, **kwargs)

    async def asend(
        self: httpx.AsyncClient, request: httpx.Request, **kwargs: Any
    ) -> httpx.Response:
        _check_secrets(request)
        return await own_asend(self, request, **kwargs)

    httpx.Client.send = send  # type: ignore[method-assign]
    httpx.AsyncClient.send = asend  # type: ignore[method-assign]
    _installed = True


def _no_redirect_elsewhere(build: Any) -> Any:
    def build_redirect_request(self: Any, request: Any, response: Any) -> Any:
        redirect = build(self, request, response)
        if _rules.get() is not None and origin(redirect.url) != origin(request.url):
            raise RedirectRefused(response.status_code, str(request.url), str(redirect.url))
        return redirect

    return build_redirect_request


def _check_secrets(request: Any) -> None:
    """Raise SecretRefused when a request to a server the user did not name carries a secret
    (in its URL, headers or body)."""
    rules = _rules.get()
    if rules is None or rules.server_trusted:
        return
    found = secret_in(_request_text(request))
    if found is not None:
        raise SecretRefused(found, f"{request.url.scheme}://{request.url.netloc.decode()}")


def _request_text(request: Any) -> str:
    parts = [str(request.url), *(f"{k}: {v}" for k, v in request.headers.items())]
    with contextlib.suppress(Exception):  # a streamed body that is not read yet: no body
        if len(request.content) < MAX_SCANNED_BODY:
            parts.append(request.content.decode("utf-8", "replace"))
    return "\n".join(parts)


def secret_in(text: str) -> str | None:
    """'$NAME' of the first credential-like environment variable whose value `text` holds
    (keymps.planning.redaction.secret_variables), or None."""
    from keymps.planning.redaction import secret_variables

    return next((f"${name}" for name, value in secret_variables().items() if value in text), None)


def origin(url: Any) -> tuple[str, str, int | None]:
    """(scheme, host, port) of an httpx.URL, the scheme's default port filled in."""
    default = {"http": 80, "https": 443}.get(url.scheme)
    return url.scheme, url.host, url.port or default
