"""How every keymps command reports a user's mistake: one line per problem, exit code 1."""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from typing import Any

import click

from keymps.errors import Interrupted, KeympsError, interrupt_name, os_error_message

INTERRUPTED_EXIT_CODE = 130
"""128 + SIGINT, what shells report for a program stopped with Ctrl-C."""


def interrupted_exit_code(interrupt: BaseException) -> int:
    """130 for Ctrl-C, 143 for SIGTERM, 129 for SIGHUP: 128 + the signal, as shells expect."""
    return interrupt.exit_code if isinstance(interrupt, Interrupted) else INTERRUPTED_EXIT_CODE


def user_errors(command: Callable[..., Any]) -> Callable[..., Any]:
    """Turn a KeympsError (or an OSError) into `error: <line>` on stderr and exit code 1, and
    Ctrl-C, SIGTERM or SIGHUP into `error: interrupted (SIGTERM)` and exit code 128 + the
    signal (130 for Ctrl-C): never a traceback."""

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except KeympsError as error:
            from keymps.planning.redaction import redact_text

            for line in redact_text(str(error)).splitlines() or ["unknown error"]:
                click.echo(f"error: {line}", err=True)
            sys.exit(1)
        except OSError as error:  # a full disk, a read-only folder ... outside any stage
            click.echo(f"error: {os_error_message(error)}", err=True)
            sys.exit(1)
        except KeyboardInterrupt as interrupt:
            click.echo(f"error: interrupted ({interrupt_name(interrupt)})", err=True)
            sys.exit(interrupted_exit_code(interrupt))

    return wrapper
