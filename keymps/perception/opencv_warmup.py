"""OpenCV's one-time set-ups, made on a background thread while a command starts.

OpenCV builds two things on a process's first use of them, with the GIL released: its Lab
conversion tables (about 100 ms of software floating point, on the first conversion to or from
Lab) and its built-in fonts (about 23 ms, on the first text measured or drawn: OpenCV 5 unpacks
its TrueType fonts). Built on the second core while a run imports its modules and loads its
task, they cost the run nothing. Neither build is safe to race with the same first use in
another thread, so code that converts to or from Lab, or measures or draws text, calls
`opencv_ready()` first: it returns at once when no warm-up was started, and after a fork (the
thread is not copied; the child has whatever the parent had built).
"""

from __future__ import annotations

import contextlib
import threading

import numpy as np

_thread: threading.Thread | None = None
_lock = threading.Lock()


def start_opencv_warmup() -> None:
    """Build OpenCV's Lab tables and fonts on a background thread (once per process)."""
    global _thread
    with _lock:
        if _thread is None:
            _thread = threading.Thread(target=_warm_up, name="keymps-opencv-warmup", daemon=True)
            _thread.start()


def opencv_ready() -> None:
    """Wait for the warm-up thread, if one was started."""
    if _thread is not None:
        _thread.join()


def _warm_up() -> None:
    with contextlib.suppress(Exception):  # the real call will report any problem
        import cv2

        cv2.cvtColor(np.zeros((1, 1, 3), np.float32), cv2.COLOR_BGR2Lab)
        cv2.getTextSize("0", cv2.FONT_HERSHEY_SIMPLEX, 1.0, 1)
