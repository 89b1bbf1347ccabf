"""The HTTP clients litellm keeps for keymps' calls, closed when the process exits.

litellm caches one client per server and key for the life of the process (its keep-alive
connections serve the next call) and at exit closes only its async clients. A synchronous
client's connection was left to the interpreter's teardown, which a program calling keymps with
warnings on reports as `ResourceWarning: unclosed <socket ...>`. The keymps command runs the
atexit handlers too before it skips that teardown (keymps.cli.app).
"""

from __future__ import annotations

import atexit
import contextlib
import inspect
import sys

_installed = False


def install() -> None:
    """Close litellm's synchronous clients at exit (registered once per process)."""
    global _installed
    if not _installed:
        atexit.register(close_synchronous_clients)
        _installed = True


def close_synchronous_clients() -> None:
    """Close every client in litellm's cache whose close is not a coroutine (litellm closes
    those itself at exit, in an event loop of its own)."""
    litellm = sys.modules.get("litellm")
    cache = getattr(litellm, "in_memory_llm_clients_cache", None)
    for client in list(getattr(cache, "cache_dict", {}).values()):
        close = getattr(client, "close", None)
        if callable(close) and not inspect.iscoroutinefunction(close):
            with contextlib.suppress(Exception):  # a client that cannot close ends with us
                close()
