"""A ceiling on the size of one VLM answer, whatever the provider, server or compression.

litellm builds its own HTTP clients per provider (the OpenAI SDK's, its own handlers, aiohttp
for async calls), and none takes a size limit: a server (one a shared task file names, say)
could answer with gigabytes, or with a few kilobytes of gzip that inflate to gigabytes, and
the whole of it would be read into memory before keymps sees a byte. Every one of those clients
reads a body through `httpx.Response.iter_bytes` or `aiter_bytes`; `install()` wraps both, and
inside `answers_capped()` (a context variable: only keymps' own calls, only in the thread or
task that makes them) a body is read at most MAX_ANSWER_BYTES at a time, inflated by keymps
itself in bounded steps, and refused with AnswerRefused as soon as it passes the limit or
arrives in an encoding keymps does not inflate. Outside keymps' calls both methods behave as
httpx's own.
"""

from __future__ import annotations

import contextlib
import contextvars
import zlib
from collections.abc import AsyncIterator, Iterable, Iterator
from typing import Any

MAX_ANSWER_BYTES = 8 * 2**20
"""The largest answer body read, after decompression: a plan is a few kilobytes of JSON."""

_limit: contextvars.ContextVar[int | None] = contextvars.ContextVar(
    "keymps_answer_limit", default=None
)
_installed = False

_INFLATED = {"gzip": zlib.MAX_WBITS | 16, "x-gzip": zlib.MAX_WBITS | 16, "deflate": zlib.MAX_WBITS}
"""Content-Encoding -> zlib's wbits (deflate is zlib, or raw deflate as some servers send it)."""


class AnswerRefused(Exception):
    """The server's answer was refused unread: too large, or encoded as keymps does not read."""

    def __init__(self, reason: str, url: str | None = None):
        self.reason = reason
        """What the server did, e.g. 'sent an answer larger than 8 MB'."""
        self.url = url
        super().__init__(reason)


@contextlib.contextmanager
def answers_capped(limit: int = MAX_ANSWER_BYTES) -> Iterator[None]:
    """Within this block (this thread, this task), HTTP answers are capped at `limit` bytes."""
    token = _limit.set(limit)
    try:
        yield
    finally:
        _limit.reset(token)


def install() -> None:
    """Wrap httpx.Response's body iterators once per process (a no-op outside answers_capped)."""
    global _installed
    if _installed:
        return
    import httpx

    own_iter, own_aiter = httpx.Response.iter_bytes, httpx.Response.aiter_bytes

    def iter_bytes(self: httpx.Response, chunk_size: int | None = None) -> Iterator[bytes]:
        limit = _limit.get()
        if limit is None or hasattr(self, "_content"):
            yield from own_iter(self, chunk_size)
            return
        inflate = _Inflater(self, limit)
        for raw in self.iter_raw():
            yield from inflate(raw)
        yield from inflate.finish()

    async def aiter_bytes(
        self: httpx.Response, chunk_size: int | None = None
    ) -> AsyncIterator[bytes]:
        limit = _limit.get()
        if limit is None or hasattr(self, "_content"):
            async for chunk in own_aiter(self, chunk_size):
                yield chunk
            return
        inflate = _Inflater(self, limit)
        async for raw in self.aiter_raw():
            for chunk in inflate(raw):
                yield chunk
        for chunk in inflate.finish():
            yield chunk

    httpx.Response.iter_bytes = iter_bytes  # type: ignore[method-assign]
    httpx.Response.aiter_bytes = aiter_bytes  # type: ignore[method-assign,assignment]
    _installed = True


class _Inflater:
    """Raw body chunks -> the answer's bytes, never holding more than the limit at once."""

    def __init__(self, response: Any, limit: int):
        try:
            self.url: str | None = str(response.request.url)
        except RuntimeError:  # a response built without a request
            self.url = None
        content_encoding = response.headers.get("content-encoding", "")
        codings = [c.strip().lower() for c in content_encoding.split(",")]
        codings = [c for c in codings if c and c != "identity"]
        if len(codings) > 1 or (codings and codings[0] not in _INFLATED):
            raise AnswerRefused(
                f"sent its answer compressed as {content_encoding!r}, which keymps did not ask for",
                self.url,
            )
        self.coding = codings[0] if codings else None
        self.limit = limit
        self.total = 0
        self._zlib: Any = None
        if self.coding in ("gzip", "x-gzip"):
            self._zlib = zlib.decompressobj(_INFLATED[self.coding])
        self._head = b""
        """HTTP's deflate: the first two bytes say whether a zlib header comes (else raw)."""

    def __call__(self, raw: bytes) -> Iterable[bytes]:
        if self.coding is None:
            self._count(len(raw))
            return [raw] if raw else []
        if self._zlib is None:  # deflate, its first two bytes not seen yet
            self._head += raw
            if len(self._head) < 2:
                return []
            raw, self._head = self._head, b""
            self._zlib = zlib.decompressobj(
                zlib.MAX_WBITS if _zlib_header(raw) else -zlib.MAX_WBITS
            )
        return list(self._inflate(raw))

    def finish(self) -> list[bytes]:
        """What zlib still holds once the body has ended (at most one match of output)."""
        if self._zlib is None and self._head:
            self._zlib = zlib.decompressobj(-zlib.MAX_WBITS)
            return [*self._inflate(self._head), *self.finish()]
        if self._zlib is None or self._zlib.eof:
            return []
        rest = self._zlib.flush()
        self._count(len(rest))
        return [rest] if rest else []

    def _inflate(self, data: bytes) -> Iterator[bytes]:
        while data and not self._zlib.eof:
            try:
                out = self._zlib.decompress(data, self.limit - self.total + 1)
            except zlib.error as error:
                raise AnswerRefused(
                    f"sent corrupt {self.coding} data ({error})", self.url
                ) from None
            self._count(len(out))
            if out:
                yield out
            data = self._zlib.unconsumed_tail

    def _count(self, size: int) -> None:
        self.total += size
        if self.total > self.limit:
            raise AnswerRefused(f"sent an answer larger than {self.limit / 2**20:g} MB", self.url)


def _zlib_header(start: bytes) -> bool:
    """True when two bytes open a zlib stream (method 8, check bits): not raw deflate."""
    return start[0] & 0x0F == 8 and (start[0] << 8 | start[1]) % 31 == 0
