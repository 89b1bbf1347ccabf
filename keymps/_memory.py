"""Memory of keymps' own processes: freed memory kept for the next allocation (glibc's malloc,
Linux), no garbage-collector passes over what start-up built, and how much memory a process may
still take (`memory_left`, for the budget of a large image: keymps.config.limits).

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
import re
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

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


def memory_left() -> tuple[int, str] | None:
    """How many bytes this process may still allocate and what bounds it: the memory this
    machine has available, the container's memory limit (cgroup v2 or v1), or the address-space
    limit (ulimit -v), whichever leaves least; None where none can be read (not Linux)."""
    found = [
        (left, why)
        for left, why in (
            (_meminfo_available(), "the memory this machine has available"),
            (_cgroup_left(), "the container's memory limit (cgroup)"),
            (_address_space_left(), "this process's address-space limit (ulimit -v)"),
        )
        if left is not None
    ]
    return min(found) if found else None


def _meminfo_available() -> int | None:
    try:
        text = Path("/proc/meminfo").read_text()
    except OSError:
        return None
    found = re.search(r"^MemAvailable:\s+(\d+) kB", text, re.MULTILINE)
    return int(found.group(1)) * 1024 if found else None


def _cgroup_left() -> int | None:
    """The limit minus the usage of this process's memory cgroup (v2, else v1), if it has one."""
    try:
        entries = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return None
    own = next((e.split(":", 2)[2] for e in entries if e.startswith("0::")), "/")
    candidates = [
        (Path("/sys/fs/cgroup") / own.lstrip("/"), "memory.max", "memory.current"),
        (Path("/sys/fs/cgroup/memory"), "memory.limit_in_bytes", "memory.usage_in_bytes"),
    ]
    for folder, limit_file, usage_file in candidates:
        try:
            limit = (folder / limit_file).read_text().strip()
            usage = int((folder / usage_file).read_text().strip())
        except (OSError, ValueError):
            continue
        if limit.isdigit() and int(limit) < 2**60:  # v1 writes a huge number for none
            return max(0, int(limit) - usage)
        return None
    return None


def _address_space_left() -> int | None:
    """The soft RLIMIT_AS minus this process's virtual size, when a limit is set."""
    try:
        import resource

        soft, _hard = resource.getrlimit(resource.RLIMIT_AS)
        status = Path("/proc/self/status").read_text()
    except (ImportError, OSError):
        return None
    size = re.search(r"^VmSize:\s+(\d+) kB", status, re.MULTILINE)
    if soft == resource.RLIM_INFINITY or size is None:
        return None
    return max(0, soft - int(size.group(1)) * 1024)
