"""Where the data shipped with keymps lives: the primitive dictionary, the prompts, the suites.

In a source checkout (and an editable install) they are the repository's own folders. A wheel
carries them inside the package, as keymps/bundled/<name> (pyproject.toml maps the folders), so
a plain `pip install` finds the same dictionary, prompts and suites.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
SOURCE_FOLDERS = {"primitives": "primitives", "prompts": "prompts", "suites": "benchmarks/suites"}
"""Each bundled folder's place in the repository."""


def bundled_dir(name: str) -> Path:
    """The bundled folder `name` (one of SOURCE_FOLDERS): installed copy first, else source."""
    installed = _PACKAGE / "bundled" / name
    if installed.is_dir():
        return installed
    return _PACKAGE.parent / SOURCE_FOLDERS[name]
