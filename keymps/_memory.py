"""Keep freed memory in the process for the next allocation (glibc's malloc, Linux).

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

import os
import sys

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
