"""Ctrl-C held back over a block that must not be cut: run.json's writing, a native import."""

from __future__ import annotations

import importlib
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Ctrl-C during the block takes effect when it ends (Python handles signals only in the
    main thread: elsewhere this does nothing)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pressed: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda number, _frame: pressed.append(number))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if pressed and previous is signal.default_int_handler:
        raise KeyboardInterrupt
    if pressed and callable(previous):
        previous(signal.SIGINT, None)


def import_whole(name: str) -> ModuleType:
    """Import a compiled module with Ctrl-C held back until its initialisation ends.

    ruckig's pybind11 initialisation creates Python enums; a KeyboardInterrupt raised inside it
    became a C++ exception nothing could catch, and the process aborted (SIGABRT, a traceback
    printed as `what():`) instead of recording the interrupt and exiting 130."""
    loaded = sys.modules.get(name)
    if loaded is not None:  # (most calls: no signal handler swapped)
        return loaded
    with interrupts_deferred():
        return importlib.import_module(name)
