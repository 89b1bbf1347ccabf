"""OpenCV text, drawn on one thread per process.

OpenCV 5 renders every font (the Hershey names included) with FreeType from gzipped built-in
fonts, and sets that up once per thread: a thread's first getTextSize or putText costs about
25 ms. The pictures runs and evals write with text (plan.png's pair numbers, the outcome's
object numbers, the marked crop a VLM sees, the direct method's plan, the eval's box plot) are
drawn here, on one thread that `prepare_text_drawing` starts early: its set-up then runs on
the other core while the run's first stages compute, and no later run thread pays it again.
"""

from __future__ import annotations

import os
import threading
from collections import deque
from collections.abc import Callable
from typing import Any, ParamSpec, TypeVar

Result = TypeVar("Result")
Arguments = ParamSpec("Arguments")


class _Call:
    """One drawing call handed to the text thread, and its outcome."""

    def __init__(self, draw: Callable[..., Any], args: tuple, kwargs: dict[str, Any]) -> None:
        self.draw, self.args, self.kwargs = draw, args, kwargs
        self.done = threading.Event()
        self.result: Any = None
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self.result = self.draw(*self.args, **self.kwargs)
        except BaseException as error:  # handed back to the caller, raised in its thread
            self.error = error
        finally:
            self.done.set()


class _TextThread:
    """A daemon thread that runs the calls handed to it, one at a time, in order.

    (concurrent.futures would do, but its import, with logging's, costs a run 7 ms.)"""

    def __init__(self) -> None:
        self.calls: deque[_Call] = deque()
        self.waiting = threading.Condition()
        self.thread = threading.Thread(target=self._serve, name="keymps-text", daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        while True:
            with self.waiting:
                while not self.calls:
                    self.waiting.wait()
                call = self.calls.popleft()
            call.run()

    def hand_over(self, call: _Call) -> None:
        with self.waiting:
            self.calls.append(call)
            self.waiting.notify()


_text_thread: _TextThread | None = None
_lock = threading.Lock()


def _set_up_text() -> None:
    import cv2

    cv2.getTextSize("0", cv2.FONT_HERSHEY_SIMPLEX, 1.0, 1)


def _thread() -> _TextThread:
    global _text_thread
    with _lock:
        if _text_thread is None:
            _text_thread = _TextThread()
            _text_thread.hand_over(_Call(_set_up_text, (), {}))
        return _text_thread


def _forget_after_fork() -> None:
    # A forked child has no copy of the thread: it starts its own on first use.
    global _text_thread, _lock
    _text_thread, _lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_after_fork)


def prepare_text_drawing() -> None:
    """Start the text thread and OpenCV's font set-up on it (once per process; returns at once)."""
    _thread()


def on_text_thread(
    draw: Callable[Arguments, Result], *args: Arguments.args, **kwargs: Arguments.kwargs
) -> Result:
    """`draw(*args, **kwargs)` on the text thread: waits for it and returns its result or
    raises its exception, as a direct call would."""
    text_thread = _thread()
    if threading.current_thread() is text_thread.thread:
        return draw(*args, **kwargs)
    call = _Call(draw, args, kwargs)
    text_thread.hand_over(call)
    call.done.wait()
    if call.error is not None:
        raise call.error
    result: Result = call.result
    return result
