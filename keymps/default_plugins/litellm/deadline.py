"""planner.timeout_s as a deadline: one VLM request ends by then, whatever the server does.

litellm's `timeout` bounds each network operation, not the request: a server that sends its
headers and then one byte a second never trips it. Here the blocking call runs in a worker
thread that is abandoned at the deadline (a daemon: it ends with the server or the process),
and the async call is cancelled, which closes its connection.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

T = TypeVar("T")


class DeadlineExceeded(Exception):
    """The request was still going at its deadline."""

    def __init__(self, seconds: float):
        self.seconds = seconds
        super().__init__(f"no complete answer within {seconds:g} s")


def call_within(seconds: float, work: Callable[[], T]) -> T:
    """work(), or DeadlineExceeded once `seconds` have passed (work's own errors pass through)."""
    outcome: dict[str, Any] = {}
    finished = threading.Event()

    def target() -> None:
        try:
            outcome["value"] = work()
        except BaseException as error:  # handed to the caller, who decides
            outcome["error"] = error
        finally:
            finished.set()

    worker = threading.Thread(target=target, name="keymps-vlm-request", daemon=True)
    worker.start()
    if not finished.wait(seconds):
        raise DeadlineExceeded(seconds)
    if "error" in outcome:
        raise outcome["error"]
    return outcome["value"]  # type: ignore[no-any-return]


async def await_within(seconds: float, work: Awaitable[T]) -> T:
    """await work, cancelled with DeadlineExceeded once `seconds` have passed."""
    try:
        return await asyncio.wait_for(work, seconds)
    except asyncio.TimeoutError:
        raise DeadlineExceeded(seconds) from None
