"""How every keymps command reports a user's mistake: one line per problem, exit code 1."""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from typing import Any

import click

from keymps.errors import KeympsError, os_error_message

INTERRUPTED_EXIT_CODE = 130
"""128 + SIGINT, what shells report for a program stopped with Ctrl-C."""


def user_errors(command: Callable[..., Any]) -> Callable[..., Any]:
    """Turn a KeympsError (or an OSError) into `error: <line>` on stderr and exit code 1, and
    Ctrl-C into `error: interrupted` and exit code 130: never a traceback."""

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
        except KeyboardInterrupt:
            click.echo("error: interrupted (Ctrl-C)", err=True)
            sys.exit(INTERRUPTED_EXIT_CODE)

    return wrapper
