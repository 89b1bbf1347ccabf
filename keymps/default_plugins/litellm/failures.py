"""What went wrong with a VLM call that got no usable answer, told from litellm's exception.

litellm wraps a refused connection, a reset, an HTML page and missing credentials alike in an
InternalServerError with a made-up status 500; the real cause is further down the exception's
chain (httpx, httpcore, h11, the socket). `classify` walks that chain and says, in words a user
acts on, what happened and whether another try can help.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from typing import Literal
from urllib.parse import urlparse

from keymps.default_plugins.litellm.request_guard import RedirectRefused, SecretRefused
from keymps.default_plugins.litellm.response_cap import AnswerRefused

Kind = Literal[
    "refused",
    "unresolved",
    "reset",
    "closed",
    "not_http",
    "html",
    "bad_json",
    "credentials",
    "unread",
    "not_utf8",
    "stream",
    "bad_chunks",
    "redirected",
    "secret",
]


@dataclass(frozen=True)
class Failure:
    kind: Kind
    text: str
    """One phrase, e.g. 'cannot connect to 127.0.0.1:8000 (connection refused)'."""
    retry: Literal["no", "briefly", "yes"]
    """'briefly': one quick retry at most (a server that is just starting)."""
    http: bool = False
    """True when the server answered HTTP at all (its status then means something)."""


_KEY_VARIABLE = re.compile(r"\b([A-Z][A-Z0-9_]*_API_KEY)\b")
_CREDENTIALS = re.compile(
    r"missing credentials|api[_ ]key (?:is )?(?:missing|not set|required)|"
    r"set the `?[A-Z0-9_]+_API_KEY",
    re.IGNORECASE,
)


def chain(error: BaseException) -> list[BaseException]:
    """The error and every cause or context below it, outermost first (cycles cut)."""
    seen: list[BaseException] = []
    current: BaseException | None = error
    while current is not None and all(current is not e for e in seen):
        seen.append(current)
        current = current.__cause__ or current.__context__
    return seen


def endpoint(errors: list[BaseException], api_base: str | None) -> str:
    """HOST:PORT the call went to: from the HTTP library's request, else from api_base."""
    for error in reversed(errors):
        if not type(error).__module__.startswith(("httpx", "httpcore")):
            continue
        try:
            url = error.request.url  # type: ignore[attr-defined]
        except (AttributeError, RuntimeError):  # httpx raises RuntimeError when unset
            continue
        return _host_port(str(url))
    return _host_port(api_base) if api_base else "the provider's endpoint"


def _host_port(url: str) -> str:
    parsed = urlparse(url if "//" in url else f"//{url}")
    host = parsed.hostname or url
    host = f"[{host}]" if ":" in host else host
    port = parsed.port or {"https": 443, "http": 80}.get(parsed.scheme)
    return f"{host}:{port}" if port else host


def redirected(error: BaseException) -> Failure | None:
    """The redirect behind a failed call, if the server redirected it: whatever the target then
    said, the redirect is the cause (a 301 or 302 turns the POST into a GET, which it refuses).
    A redirect to another server was not followed at all, and a request carrying a secret to a
    server the user did not name not sent (keymps' request_guard)."""
    for e in chain(error):
        if isinstance(e, SecretRefused):
            return Failure(
                "secret",
                f"the request to {_host_port(e.url)} would have carried the value of {e.what} "
                "(litellm reads it itself), and only the task file chose that server: not sent; "
                f"unset {e.what[1:]}, or pass the server with --api-base if it is yours",
                "no",
            )
        if isinstance(e, RedirectRefused):
            return Failure(
                "redirected",
                f"{_host_port(e.source)} redirected the request (HTTP {e.status}) to "
                f"{_host_port(e.target)}, another server: not followed, as the request carries "
                f"your key, the image and the prompt; {_fix(e.target)} if that server is meant",
                "no",
                http=True,
            )
    for e in chain(error):
        response = getattr(e, "response", None)
        history = getattr(response, "history", None)
        if not history:
            continue
        first = history[0]
        to = str(first.headers.get("location", "another address"))
        method = getattr(getattr(response, "request", None), "method", "POST")
        turned = ", which turned the POST into a GET" if method == "GET" else ""
        return Failure(
            "redirected",
            f"{_host_port(str(first.request.url))} redirected the request (HTTP "
            f"{first.status_code}) to {to}{turned}: {_fix(to)}",
            "no",
            http=True,
        )
    return None


def _fix(target: str) -> str:
    base = target.removesuffix("/chat/completions")
    return f"set planner.api_base to {base}" if base != target else "check planner.api_base"


def classify(error: BaseException, api_base: str | None) -> Failure | None:
    """The failure in words, or None when the chain holds nothing more specific than litellm's
    own class (an HTTP status from a real answer, a timeout ...). A redirect is told apart
    first, by `redirected`."""
    errors = chain(error)
    where = endpoint(errors, api_base)
    unread = _unread(errors, where)
    if unread is not None:
        return unread
    messages = " | ".join(str(e) for e in errors)
    return (
        _unreachable(errors, messages, where)
        or _broken_connection(errors, where)
        or _not_one_json_answer(errors, messages, where)
        or _no_credentials(messages)
    )


def _unread(errors: list[BaseException], where: str) -> Failure | None:
    """An answer keymps refused to read: too large, or compressed as keymps does not read."""
    for e in errors:
        if isinstance(e, AnswerRefused):
            at = _host_port(e.url) if e.url else where
            return Failure("unread", f"{at} {e.reason}: refused unread", "no", http=True)
    return None


def _unreachable(errors: list[BaseException], messages: str, where: str) -> Failure | None:
    """No connection at all: refused, or a host name that does not resolve."""
    if (
        any(isinstance(e, ConnectionRefusedError) for e in errors)
        or "Connection refused" in messages
    ):
        return Failure("refused", f"cannot connect to {where} (connection refused)", "briefly")
    if "Name or service not known" in messages or "nodename nor servname" in messages:
        return Failure("unresolved", f"cannot resolve the host of {where}", "no")
    return None


def _broken_connection(errors: list[BaseException], where: str) -> Failure | None:
    """The first error in the chain that tells of a connection broken or an answer that is not
    HTTP, not text or not a number Python reads."""
    for e in errors:
        text = str(e)
        name = type(e).__name__
        if isinstance(e, ConnectionResetError) or "disconnected without sending" in text:
            return Failure("reset", f"connection reset by {where} before any answer", "yes")
        if name == "RemoteProtocolError" and "peer closed connection" in text:
            return Failure("closed", f"{where} closed the connection mid-answer", "yes")
        if name == "RemoteProtocolError" and "illegal status line" in text:
            return Failure("not_http", f"{where} did not answer in HTTP", "yes", http=False)
        if name == "RemoteProtocolError" and "chunk" in text:
            return Failure("bad_chunks", f"{where} sent a malformed chunked answer", "yes")
        if isinstance(e, UnicodeDecodeError):
            return Failure(
                "not_utf8", f"{where} answered with bytes that are not UTF-8 text", "no", http=True
            )
        if isinstance(e, ValueError) and "integer string conversion" in text:
            return Failure(
                "bad_json", f"{where} answered with a number of over 4300 digits", "no", http=True
            )
    return None


def _not_one_json_answer(errors: list[BaseException], messages: str, where: str) -> Failure | None:
    """An HTTP answer that is a stream, an HTML page or broken JSON instead of one JSON
    document."""
    # litellm quotes the stream when it is labelled text/event-stream; the JSON parser holds it
    # when it is labelled JSON
    streamed = [e.doc for e in errors if isinstance(e, json.JSONDecodeError)]
    if re.search(r"invalid response from LLM endpoint\. Received: '?data:", messages) or any(
        re.match(r"\s*(data|event):", doc) for doc in streamed
    ):
        return Failure(
            "stream",
            f"{where} answered with a stream of server-sent events, though keymps asked for one "
            "JSON answer (stream: false): is planner.api_base an OpenAI-compatible chat API?",
            "no",
            http=True,
        )
    received = re.search(r"Received:? '?\s*(<)", messages)
    if received or re.search(r"<!doctype html|<html", messages, re.IGNORECASE):
        return Failure(
            "html",
            f"{where} answered with an HTML page, not JSON: is planner.api_base the API's URL "
            "(OpenAI-compatible servers usually end in /v1)?",
            "no",
            http=True,
        )
    if streamed:
        return Failure("bad_json", f"{where} answered with broken JSON", "yes", http=True)
    return None


def _no_credentials(messages: str) -> Failure | None:
    """litellm's complaint of a missing API key, with the variable it names."""
    if not _CREDENTIALS.search(messages):
        return None
    variable = _KEY_VARIABLE.search(messages)
    how = f"set {variable.group(1)}" if variable else "set the provider's API key variable"
    return Failure(
        "credentials", f"no API key: {how} (or name another variable in planner.api_key_env)", "no"
    )
