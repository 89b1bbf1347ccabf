"""The `keymps` command line: one module per command group (app.py holds the root group)."""

from keymps.cli.app import main

__all__ = ["main"]
