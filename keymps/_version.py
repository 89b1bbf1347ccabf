"""The keymps version (one place; pyproject.toml reads it too)."""

__version__ = "0.2.0"
"""The installed keymps' version (PEP 440); CHANGELOG.md says what each version changed."""
