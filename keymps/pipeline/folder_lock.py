"""One run at a time in a run folder: an advisory lock held from the first write to run.json.

Two runs into the same `--out` would interleave their files (run.rrd, run.json ...); the
second one refuses at once instead. The lock is `fcntl.flock` on `.keymps.lock` in the folder:
the kernel releases it when the process ends however it ends, so a crashed run leaves no stale
lock (the empty file stays, harmlessly).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import IO

from keymps.errors import KeympsError

LOCK_FILE = ".keymps.lock"


class FolderLock:
    """Held while a run writes into `folder`; `release()` (or process exit) frees it."""

    def __init__(self, folder: Path):
        self.folder = folder
        self._handle: IO[str] | None = None

    def acquire(self) -> FolderLock:
        try:
            import fcntl
        except ImportError:  # Windows: no advisory locks; the folder is not guarded
            return self
        path = self.folder / LOCK_FILE
        try:
            handle = path.open("a+", encoding="utf-8")
        except OSError as error:
            raise KeympsError(
                f"run folder {self.folder}: cannot write {LOCK_FILE} in it: {error.strerror}"
            ) from None
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.seek(0)
            holder = handle.read().strip() or "another process"
            handle.close()
            raise KeympsError(
                f"run folder {self.folder} is in use by another keymps run ({holder}); "
                "wait for it to finish or choose another --out"
            ) from None
        try:  # who holds it, for the message above (informational: a full disk may refuse it)
            handle.seek(0)
            handle.truncate()
            handle.write(f"pid {os.getpid()}")
            handle.flush()
        except OSError:
            pass
        self._handle = handle
        return self

    def release(self) -> None:
        if self._handle is not None:
            self._handle.close()  # closing the descriptor releases the flock
            self._handle = None
