"""keymps.text_drawing: every picture with text is drawn on one thread, as a direct call would."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from keymps.text_drawing import on_text_thread, prepare_text_drawing


def _thread_name() -> str:
    return threading.current_thread().name


def test_calls_run_on_one_thread_that_is_not_the_callers() -> None:
    prepare_text_drawing()
    names = {on_text_thread(_thread_name) for _ in range(5)}
    callers = []
    worker = threading.Thread(target=lambda: callers.append(on_text_thread(_thread_name)))
    worker.start()
    worker.join()
    assert len(names | set(callers)) == 1
    assert names != {threading.current_thread().name}


def test_results_and_arguments_pass_through() -> None:
    assert on_text_thread(lambda a, *, b: (a, b), 1, b="two") == (1, "two")


def test_an_exception_reaches_the_caller_as_it_was() -> None:
    class Broken(Exception):
        pass

    def fail() -> None:
        raise Broken("no ink")

    with pytest.raises(Broken, match="no ink"):
        on_text_thread(fail)
    assert on_text_thread(lambda: "still serving") == "still serving"


def test_a_call_from_the_text_thread_runs_in_place() -> None:
    assert on_text_thread(lambda: on_text_thread(_thread_name)) == on_text_thread(_thread_name)


def test_opencv_text_drawn_there_is_what_a_direct_call_draws() -> None:
    import cv2

    def numbered() -> np.ndarray:
        canvas = np.zeros((40, 80, 3), np.uint8)
        cv2.putText(canvas, "12", (5, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 200, 0), 2)
        return canvas

    assert np.array_equal(on_text_thread(numbered), numbered())


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork is POSIX")
def test_a_forked_child_draws_on_a_thread_of_its_own() -> None:
    parent_thread = on_text_thread(threading.get_native_id)
    read, write = os.pipe()
    child = os.fork()
    if child == 0:  # pragma: no cover - runs in the child
        try:
            ident = on_text_thread(threading.get_native_id)
            os.write(
                write, b"ok" if ident not in (parent_thread, threading.get_native_id()) else b"no"
            )
        finally:
            os._exit(0)
    os.close(write)
    _, status = os.waitpid(child, 0)
    answer = os.read(read, 2)
    os.close(read)
    assert os.WEXITSTATUS(status) == 0
    assert answer == b"ok"
