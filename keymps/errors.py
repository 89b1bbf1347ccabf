"""Errors a user can act on: printed as one line, never with a traceback."""

from __future__ import annotations

import errno
import signal

_MAX_LISTED = 12
"""A SafetyError's message lists this many problems, then counts the rest."""


class KeympsError(Exception):
    """A user-facing problem; str(error) is a complete, one-line message."""

    run: object = None
    """The Run a failed `run_task` leaves behind (its folder and warnings explain the error)."""


class TaskFileError(KeympsError):
    """A task file (or an input it names) is invalid; one message per problem."""

    def __init__(self, problems: list[str]):
        self.problems = problems
        super().__init__("\n".join(problems))


class SafetyError(KeympsError):
    """The trajectory is unsafe (or not validated); `problems` lists every finding.

    Args:
        problems: Every finding, one line each; the message lists the first 12 and counts the
            rest.
    """

    def __init__(self, problems: list[str]):
        self.problems = problems
        """Every finding, one line each."""
        shown = problems[:_MAX_LISTED]
        more = f"; and {len(problems) - _MAX_LISTED} more" if len(problems) > _MAX_LISTED else ""
        super().__init__("safety: " + "; ".join(shown) + more)


_WRITE_ERRORS = {errno.ENOSPC, errno.EROFS, errno.EDQUOT, errno.EFBIG}


def os_error_message(error: OSError) -> str:
    """One line for a failed file operation, naming the path ('cannot write PATH: No space ...')."""
    names = [str(name) for name in (error.filename, error.filename2) if name is not None]
    where = " -> ".join(names) if names else "a file"
    action = "write" if error.errno in _WRITE_ERRORS else "access"
    return f"cannot {action} {where}: {error.strerror or error}"


class Interrupted(KeyboardInterrupt):
    """Ctrl-C, SIGTERM or SIGHUP, raised in the main thread by the handler the keymps command
    installs (keymps.interrupts): a KeyboardInterrupt, so every `except KeyboardInterrupt` (an
    executor stopping the arm) treats the three alike."""

    def __init__(self, signum: int = signal.SIGINT):
        self.signum = int(signum)
        super().__init__(self.name)

    def __reduce__(self) -> tuple[type[Interrupted], tuple[int]]:
        return Interrupted, (self.signum,)  # (args holds the name, not the number)

    @property
    def name(self) -> str:
        """How the user stopped it: Ctrl-C, SIGTERM, SIGHUP."""
        if self.signum == signal.SIGINT:
            return "Ctrl-C"
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        """128 + the signal's number, what shells report (130 for Ctrl-C, 143 for SIGTERM)."""
        return 128 + self.signum


def interrupt_name(interrupt: BaseException) -> str:
    """What stopped the command, in the words its messages use.

    Args:
        interrupt: a KeyboardInterrupt (the keymps command raises `Interrupted` for Ctrl-C,
            SIGTERM and SIGHUP; a plain KeyboardInterrupt is a Ctrl-C).

    Returns:
        'Ctrl-C', 'SIGTERM' or 'SIGHUP'.
    """
    return interrupt.name if isinstance(interrupt, Interrupted) else "Ctrl-C"


class RunInterrupted(KeympsError):
    """A run stopped by the user (Ctrl-C, SIGTERM, SIGHUP): what run.json records; the
    KeyboardInterrupt goes on."""

    def __init__(self, running: str | None, done: str | None = None, by: str = "Ctrl-C"):
        self.stage = running
        if running:
            where = f"during stage {running!r}"
        else:
            where = f"after stage {done!r}" if done else "before its first stage"
        who = "the user (Ctrl-C)" if by == "Ctrl-C" else by
        super().__init__(f"interrupted by {who} {where}; nothing after it ran")


class StageError(KeympsError):
    """A pipeline stage could not produce its result; nothing after it runs.

    The message names the stage once ("detect: no object found"); `detail` keeps the error the
    stage raised (a SafetyError's list of problems, say) for run.json.

    Args:
        stage: The stage's name (one of keymps.types.STAGES).
        message: One line; a leading `"<stage>: "` is dropped, so the stage is named once.
        detail: The error the stage raised, when there was one.
    """

    def __init__(self, stage: str, message: str, detail: BaseException | None = None):
        self.stage = stage
        """The stage that failed."""
        self.message = message.removeprefix(f"{stage}: ")
        """The problem, without the stage's name."""
        self.detail = detail
        """The error the stage raised (a SafetyError with its problems ...), or None."""
        super().__init__(f"{stage}: {self.message}")


class ImageSourceError(StageError):
    """An image source could not produce the scene image (raise it from `load`).

    Args:
        message: One line naming what is wrong ("camera 0 opened but returned no frame").
    """

    def __init__(self, message: str):
        super().__init__("image", message)


class DetectionError(StageError):
    """A detector could not find the object in the scene image (raise it from `detect`).

    Args:
        message: One line saying what was found instead ("no object found: nothing of at
            least N px differs from the board's colour model ...").
    """

    def __init__(self, message: str):
        super().__init__("detect", message)
