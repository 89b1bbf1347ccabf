"""Memory settings of keymps' own processes: freed memory kept for the next allocation (glibc's
malloc, Linux), and no garbage-collector passes over what start-up built.

A run allocates and frees arrays of the same sizes stage after stage (full-image planes in the
detector, per-sample columns in timing, checking and the simulator). By default glibc gives
blocks freed at the top of its heap back to the kernel once 256 KB or so are free there, and
serves large blocks by mmap; every new array then costs a page fault per 4 KB page it touches:
about 3,000 per board detection (7 ms of 32). With these thresholds the freed blocks are reused
instead, at the price of keeping up to TRIM_THRESHOLD of freed memory resident. Only the keymps
command and its eval workers call this (their processes are keymps' own); a program that calls
`run_task` keeps its own allocator settings.
"""

from __future__ import annotations

import gc
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

MMAP_THRESHOLD = 32 << 20
"""Blocks under this come from the heap, not from mmap (glibc's own maximum for its dynamic
threshold)."""
TRIM_THRESHOLD = 128 << 20
"""Freed memory at the heap's top is returned to the kernel only beyond this."""

_M_TRIM_THRESHOLD = -1  # mallopt parameters, from glibc's malloc.h
_M_MMAP_THRESHOLD = -3
_EXPORTED = ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TOP_PAD_")


def keep_freed_memory() -> bool:
    """Set the thresholds; False (nothing changed) off glibc or when a MALLOC_* variable the
    user exported already says how."""
    if not sys.platform.startswith("linux") or any(name in os.environ for name in _EXPORTED):
        return False
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's C library
    except (AttributeError, OSError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )


@contextmanager
def collector_paused_for_start_up() -> Iterator[Callable[[], None]]:
    """Turn Python's cyclic garbage collector off for a command's start-up; the callable this
    yields ends start-up, and so does leaving the block.

    Start-up (imports, pydantic's schemas, the plugin manager, the robot model) makes about
    50,000 container objects that live as long as the process, and next to no garbage in
    cycles: the collector's 120 passes over them cost `keymps run` 30-45 ms and free nothing.
    Ending start-up freezes every object made so far (gc.freeze: the collector never scans them
    again) and turns the collector back on for the stages; leaving the block unfreezes them
    (unless something had frozen objects before), so that a process that goes on (a test
    calling the command in-process) has its collector as it was.
    """
    was_enabled = gc.isenabled()
    was_frozen = gc.get_freeze_count() > 0
    gc.disable()
    ended = False

    def end_start_up() -> None:
        nonlocal ended
        if not ended:
            ended = True
            gc.freeze()
            if was_enabled:
                gc.enable()

    try:
        yield end_start_up
    finally:
        end_start_up()
        if not was_frozen:
            gc.unfreeze()
