"""Whose turn it is to compute in an eval process: one run at a time, none while it waits.

The GIL lets one thread run Python at a time anyway; left to itself it switches between the
runs of a process every few milliseconds, so runs started together all finish their CPU work
late, together, and their VLM calls go out in a bunch. A run that holds the turn computes to its
VLM call undisturbed; while it waits for the answer (keymps.eval.broker gives the turn up) the
next run computes. The first calls go out one run's work apart instead of all runs' work late.

Only for runs whose VLM calls go through the broker (the litellm backend): a plugin backend that
waits inside its own complete() would keep the turn, so its runs get an inactive turn and share
the core as threads do.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

Result = TypeVar("Result")


class CpuTurn:
    """A lock that the thread holding it gives up while it waits for something else."""

    def __init__(self, active: bool = True) -> None:
        self.active = active
        """False: run() calls the function at once, nothing is ever waited for."""
        self._lock = threading.Lock()
        self._holder = threading.local()

    def run(self, function: Callable[..., Result], *args: Any) -> Result:
        """Call function(*args) holding the turn (waiting for it first)."""
        if not self.active:
            return function(*args)
        with self._lock:
            self._holder.holding = True
            try:
                return function(*args)
            finally:
                self._holder.holding = False

    @contextlib.contextmanager
    def given_up(self) -> Iterator[None]:
        """Let other runs compute inside the block (a no-op for a thread without the turn)."""
        if not getattr(self._holder, "holding", False):
            yield
            return
        self._holder.holding = False
        self._lock.release()
        try:
            yield
        finally:
            self._lock.acquire()
            self._holder.holding = True
