"""A VLM request never follows a redirect to another server.

litellm's HTTP clients (the OpenAI SDK's, its own handlers for Anthropic, Gemini ..., httpx
over aiohttp for keymps eval) follow redirects, and httpx drops only the `Authorization` header
on the way to another origin: Anthropic's `x-api-key` and Gemini's `x-goog-api-key` went along
to whatever host and port a 302 or 307 from the user's own server named, and so did the body
(the image, the prompt). All of them build the next request in httpx's
`_build_redirect_request`; `install()` wraps it on httpx.Client and httpx.AsyncClient, and
inside `same_origin_only()` (a context variable: only keymps' own calls, only in the thread or
task that makes them) a redirect to another scheme, host or port raises RedirectRefused before
anything is sent there. A redirect on the same server is followed as before; outside keymps'
calls httpx behaves as its own.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator
from typing import Any

_active: contextvars.ContextVar[bool] = contextvars.ContextVar(
    "keymps_same_origin_only", default=False
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


@contextlib.contextmanager
def same_origin_only() -> Iterator[None]:
    """Within this block (this thread, this task), a redirect to another origin raises."""
    token = _active.set(True)
    try:
        yield
    finally:
        _active.reset(token)


def install() -> None:
    """Wrap httpx's redirect step once per process (a no-op outside same_origin_only)."""
    global _installed
    if _installed:
        return
    import httpx

    for client in (httpx.Client, httpx.AsyncClient):
        guarded = _guarded(client._build_redirect_request)
        client._build_redirect_request = guarded  # type: ignore[method-assign]
    _installed = True


def _guarded(build: Any) -> Any:
    def build_redirect_request(self: Any, request: Any, response: Any) -> Any:
        redirect = build(self, request, response)
        if _active.get() and origin(redirect.url) != origin(request.url):
            raise RedirectRefused(response.status_code, str(request.url), str(redirect.url))
        return redirect

    return build_redirect_request


def origin(url: Any) -> tuple[str, str, int | None]:
    """(scheme, host, port) of an httpx.URL, the scheme's default port filled in."""
    default = {"http": 80, "https": 443}.get(url.scheme)
    return url.scheme, url.host, url.port or default
