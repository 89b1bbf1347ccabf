"""Where the warm planner listens: a Unix socket in a folder that only its user can open.

The folder is `$XDG_RUNTIME_DIR/keymps` when that variable names a folder of the user's that
nobody else may write to, else `/tmp/keymps-<uid>`. Whoever makes it, it must be a real folder
(not a link), owned by the user, with mode 0700: anything else is refused in one line, never
used or repaired (someone else may have made it to listen in). Each installation of keymps (its
Python, its keymps folder, its version) has its own socket, so that two virtual environments
never answer each other's runs with other code.
"""

from __future__ import annotations

import hashlib
import os
import socket
import stat
import struct
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from keymps._version import __version__
from keymps.errors import KeympsError

MAX_SOCKET_PATH = 107
"""Bytes in a Unix socket's path (sun_path holds 108, the last one a NUL)."""


def supported() -> bool:
    """Unix sockets with the peer's credentials (Linux): the warm planner's condition."""
    return hasattr(socket, "AF_UNIX") and hasattr(socket, "SO_PEERCRED")


def _nobody_else_writes(folder: Path) -> bool:
    try:
        info = folder.lstat()
    except OSError:
        return False
    return (
        stat.S_ISDIR(info.st_mode)
        and info.st_uid == os.getuid()
        and not info.st_mode & (stat.S_IWGRP | stat.S_IWOTH)
    )


def planner_folder() -> Path:
    """The warm planner's folder (not created here)."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime and Path(runtime).is_absolute() and _nobody_else_writes(Path(runtime)):
        return Path(runtime) / "keymps"
    return Path(tempfile.gettempdir()) / f"keymps-{os.getuid()}"


def installation_tag() -> str:
    """Tells this installation's planner from another's: Python, keymps' folder, version."""
    where = f"{sys.prefix}\n{Path(__file__).resolve().parents[2]}\n{__version__}"
    return hashlib.sha256(where.encode()).hexdigest()[:12]


@dataclass(frozen=True)
class Place:
    """The warm planner's files: its socket, its lock (held while it runs) and its log."""

    folder: Path

    @classmethod
    def for_user(cls) -> Place:
        return cls(planner_folder())

    @property
    def socket(self) -> Path:
        return self.folder / f"planner-{installation_tag()}.sock"

    @property
    def lock(self) -> Path:
        return self.folder / f"planner-{installation_tag()}.lock"

    @property
    def log(self) -> Path:
        return self.folder / f"planner-{installation_tag()}.log"

    def check(self, create: bool = False) -> None:
        """Raise KeympsError unless the folder is the user's alone (made, mode 0700, when
        `create` and missing) and the socket's path fits a Unix socket address."""
        if not supported():
            raise KeympsError(
                "the warm planner needs Unix sockets that tell the peer's user (Linux)"
            )
        if create:
            try:
                self.folder.mkdir(mode=0o700, exist_ok=True)
            except OSError as error:
                raise KeympsError(
                    f"cannot make the warm planner's folder {self.folder}: {error.strerror}"
                ) from None
        problem = folder_problem(self.folder)
        if problem:
            raise KeympsError(problem)
        if len(os.fsencode(self.socket)) > MAX_SOCKET_PATH:
            raise KeympsError(
                f"the warm planner's socket path {self.socket} is longer than a Unix socket "
                f"address allows ({MAX_SOCKET_PATH} bytes): set XDG_RUNTIME_DIR to a shorter folder"
            )


def folder_problem(folder: Path) -> str | None:
    """Why `folder` may not hold the warm planner's socket, or None when it may."""
    try:
        info = folder.lstat()
    except FileNotFoundError:
        return f"the warm planner's folder {folder} does not exist"
    except OSError as error:
        return f"cannot check the warm planner's folder {folder}: {error.strerror}"
    if not stat.S_ISDIR(info.st_mode):
        return (
            f"the warm planner's folder {folder} is not a folder (a link or a file): remove it, "
            "or set XDG_RUNTIME_DIR to a folder of yours"
        )
    if info.st_uid != os.getuid():
        return (
            f"the warm planner's folder {folder} belongs to user {info.st_uid}, not to you "
            f"({os.getuid()}): not used; remove it, or set XDG_RUNTIME_DIR to a folder of yours"
        )
    if info.st_mode & 0o077:
        return (
            f"the warm planner's folder {folder} has mode {stat.S_IMODE(info.st_mode):04o}: "
            "others may open it; not used (it must be 0700: chmod 700 it, or remove it)"
        )
    return None


def peer(connection: socket.socket) -> tuple[int, int]:
    """(pid, uid) of the process at the other end of a Unix socket, from the kernel."""
    size = struct.calcsize("3i")
    pid, uid, _gid = struct.unpack(
        "3i", connection.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, size)
    )
    return pid, uid
