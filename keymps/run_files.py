"""Writing a run folder's files: atomically, images encoded, and the names the run keeps."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import IO, Any

from keymps.errors import KeympsError

IMAGE_FORMATS = ("png", "jpg")
JPEG_QUALITY = 92
PNG_COMPRESSION = 0
"""Run-folder PNGs are stored, not deflated: the same pixels encoded about eight times faster
(about 1 ms for a 600x360 image instead of 8), in files about twice as large (0.65 MB there)."""

RUN_OWN_FILES = (
    "run.json",
    "run.rrd",
    *(f"{stem}.{suffix}" for stem in ("plan", "plan_photo") for suffix in IMAGE_FORMATS),
)
"""What the run itself writes in its folder whichever executor runs, beside trajectory.csv
(which the file executor names too: the same CSV), vlm/ and its hidden lock and temporary
files: no plugin option may name one of them (keymps.plugin.RunFolderPath)."""


def image_file(folder: Path, stem: str, image_format: str) -> Path:
    """The file of image `stem` (plan, outcome) in `folder`, for one of IMAGE_FORMATS."""
    return folder / f"{stem}.{image_format}"


def write_image(path: Path, image: Any) -> Path:
    """Write a BGR image atomically; the suffix (.png or .jpg) chooses the format."""
    import cv2

    if path.suffix == ".jpg":
        options = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]
    else:  # unfiltered: filtering only helps deflate, which is off
        options = [
            cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION,
            cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE,
        ]  # fmt: skip
    ok, encoded = cv2.imencode(path.suffix, image, options)
    if not ok:
        raise KeympsError(f"cannot encode {path} as {path.suffix}")
    return write_atomically(path, encoded.tobytes())


@contextmanager
def open_atomically(path: Path, text: bool = True) -> Iterator[IO[Any]]:
    """A file handle whose content appears at `path` only when the block ends without error.

    It writes a hidden temporary file beside `path` and renames it over `path`: a reader, a
    full disk or a Ctrl-C never leaves a half-written or empty file (the old one, if any,
    stays). An OSError always names the path (a full disk's write error names none).
    """
    temporary = path.with_name(f".{path.name}.{os.getpid()}-{os.urandom(4).hex()}.tmp")
    try:
        descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(descriptor, "w" if text else "wb", encoding="utf-8" if text else None) as f:
            yield f
        os.replace(temporary, path)
    except OSError as error:
        _remove(temporary)
        raise OSError(error.errno, error.strerror, str(path)) from None
    except BaseException:
        _remove(temporary)
        raise


def write_atomically(path: Path, data: str | bytes) -> Path:
    """Write text (UTF-8) or bytes to `path` through open_atomically."""
    with open_atomically(path, text=isinstance(data, str)) as handle:
        handle.write(data)
    return path


def _remove(path: Path) -> None:
    with suppress(OSError):
        path.unlink()
