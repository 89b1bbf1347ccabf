"""How every keymps command reports a user's mistake: one line per problem, exit code 1."""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from typing import Any

import click

from keymps.errors import KeympsError


def user_errors(command: Callable[..., Any]) -> Callable[..., Any]:
    """Turn a KeympsError into `error: <line>` on stderr and exit code 1, never a traceback."""

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except KeympsError as error:
            from keymps.planning.redaction import redact_text

            for line in redact_text(str(error)).splitlines() or ["unknown error"]:
                click.echo(f"error: {line}", err=True)
            sys.exit(1)

    return wrapper
