"""Ctrl-C, SIGTERM and SIGHUP as one orderly stop; stop signals held back over a block that must
not be cut (run.json's writing, stopping the arm, a native import)."""

from __future__ import annotations

import importlib
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType
from typing import Any

from keymps.errors import Interrupted

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""What a terminal, a service manager or a closed SSH session sends to stop a program."""

INSIST_AFTER_S = 3.0
"""A second stop signal within this long of the first is held back while the first one's stop
runs (the arm stopping, run.json being written); a later one interrupts that stop too."""

_received: list[tuple[int, float]] = []
"""(signal, monotonic time) of every stop signal the command's handler saw."""


def _stop_the_command(signum: int, _frame: Any) -> None:
    _received.append((signum, time.monotonic()))
    first = _received[0][1]
    if len(_received) == 1 or time.monotonic() - first > INSIST_AFTER_S:
        raise Interrupted(signum)


@contextmanager
def signals_stop_the_command() -> Iterator[list[int]]:
    """Within the block (the keymps command), Ctrl-C, SIGTERM and SIGHUP raise `Interrupted` in
    the main thread: the same orderly stop for the three (an executor stops the arm, run.json
    records `interrupted`). A second signal soon after the first waits for that stop to end.
    Yields the list of the signals received (still filled after the block)."""
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    previous = {number: signal.signal(number, _stop_the_command) for number in STOP_SIGNALS}
    try:
        yield received
    finally:
        received.extend(number for number, _ in _received)
        for number, handler in previous.items():
            # a command a signal stopped is exiting: a second Ctrl-C 50 ms later must not cut
            # that exit short with Python's own KeyboardInterrupt
            signal.signal(number, signal.SIG_IGN if received else handler)
        _received.clear()


def handling_signals() -> bool:
    """Whether the keymps command's handler is installed (a KeyboardInterrupt without a signal
    then came from code, a plugin's, not from the user)."""
    return signal.getsignal(signal.SIGINT) is _stop_the_command


def signals_received() -> int:
    """How many stop signals the command's handler has seen (0 outside the command)."""
    return len(_received)


def first_signal() -> int:
    """The first stop signal the command's handler saw (SIGINT when none was)."""
    return _received[0][0] if _received else signal.SIGINT


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold Ctrl-C, SIGTERM and SIGHUP back until the block ends (stopping an arm, a write).

    The first signal held is then delivered to whatever handled it before. Python handles
    signals only in the main thread: elsewhere this does nothing.

    Yields:
        None, once: the block runs with the signals held.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pressed: list[int] = []
    previous = {
        number: signal.signal(number, lambda number, _frame: pressed.append(number))
        for number in STOP_SIGNALS
    }
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
    if pressed:  # to whatever handled it before: the command's, Python's Ctrl-C, the default
        signal.raise_signal(pressed[0])


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
